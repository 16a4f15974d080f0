"""The denoising table's settings, rows and results (``benchmarks/denoise_table.py``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/denoise_table.py
    import common  # type: ignore[no-redef]

from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.metrics import EvalResult
from mdvae_cli.motion.motion import Motion

REPO = Path(__file__).resolve().parents[1]
SIGMAS = (0.10, 0.15, 0.20)
REFERENCE_SIGMA = 0.15
GAUSSIAN_GRID = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0)
SAVGOL_GRID = tuple(
    (w, p) for w in (5, 7, 9, 11, 15, 19, 25, 31) for p in (1, 2, 3, 4) if p < w - 1
)
CURVE_STEPS = (0, 20, 50, 100, 250)

ROW_GT = "Ground truth"
ROW_OBS = "Observations"
ROW_GAUSSIAN = "Gaussian filter"
ROW_SAVGOL = "Savitzky-Golay filter"
ROW_REGRESSION = "Regression mode"
ROW_OPTIMIZATION = "Optimization mode"
ROW_OFFSET = "Regression + offset + blend (--feet off)"
ROW_OFFSET_FEET = "Default (offset + blend + feet lock)"
ROW_OPTIMIZATION_OFFSET = "Optimization + offset"
ROW_REFINE = "Latent refinement"
ROW_REGRESSION_MIRROR = "Regression + mirror"
ROW_REFINE_MIRROR = "Latent refinement + mirror"
ROWS = (
    ROW_GT, ROW_OBS, ROW_GAUSSIAN, ROW_SAVGOL, ROW_REGRESSION, ROW_REGRESSION_MIRROR, ROW_OFFSET,
    ROW_OFFSET_FEET, ROW_OPTIMIZATION, ROW_OPTIMIZATION_OFFSET, ROW_REFINE, ROW_REFINE_MIRROR,
)  # fmt: skip
FILTER_ROWS = (ROW_GAUSSIAN, ROW_SAVGOL)

SECTION_BEGIN = "<!-- denoise_table:begin (written by benchmarks/denoise_table.py) -->"
SECTION_END = "<!-- denoise_table:end -->"


def section_markers(split: str) -> tuple[str, str]:
    """The markers of a split's section in docs/benchmarks.md (the test split's are the
    original ones)."""
    if split == "test":
        return SECTION_BEGIN, SECTION_END
    return (
        f"<!-- denoise_table:begin split={split} (written by benchmarks/denoise_table.py) -->",
        f"<!-- denoise_table:end split={split} -->",
    )


Process = Callable[[list[Motion]], list[Motion]]


@dataclass
class TableSettings:
    """What the table is computed with (saved in the report).

    sigmas: noise levels (rad); reference_sigma: one of them, the level for filter tuning,
    speeds, ratios and the plot; optimize_steps: optimisation-mode steps in the table;
    curve_steps: steps plotted (0 = regression mode); window/stride: denoiser windows (30 Hz
    frames); lr, seed: optimisation mode (seed also fixes the noise);
    refine_steps, refine_lr, refine_offset: the latent refinement row;
    single_clip_repeats: timed repeats of the one-clip measurement.
    """

    sigmas: tuple[float, ...] = SIGMAS
    reference_sigma: float = REFERENCE_SIGMA
    gaussian_grid: tuple[float, ...] = GAUSSIAN_GRID
    savgol_grid: tuple[tuple[int, int], ...] = SAVGOL_GRID
    optimize_steps: int = 50
    curve_steps: tuple[int, ...] = CURVE_STEPS
    window: int = 60
    stride: int = 45
    lr: float = 3e-4
    seed: int = 0
    refine_steps: int = RefineConfig.steps
    refine_lr: float = 0.1
    refine_offset: float = RefineConfig.offset_std
    single_clip_repeats: int = 5
    #: the method rows to run (None = all of ROWS; the filters, ground truth and observations
    #: always run)
    rows: tuple[str, ...] | None = None


@dataclass
class FilterTuning:
    """Grid search of the filters on val clips: V2V (cm) of every setting, and the winners."""

    noise_sigma: float
    clips: int
    gaussian_scores: dict[float, float]
    savgol_scores: dict[tuple[int, int], float]
    observations_v2v: float

    @property
    def gaussian_sigma(self) -> float:
        return min(self.gaussian_scores, key=self.gaussian_scores.get)

    @property
    def savgol(self) -> tuple[int, int]:
        return min(self.savgol_scores, key=self.savgol_scores.get)


@dataclass
class RowResult:
    """One line of the table. results: sigma -> metrics; speed: the file-to-file run at the
    speed sigma; one_clip_s: one clip alone, warm (median seconds)."""

    name: str
    params: str = ""
    results: dict[float, EvalResult] = field(default_factory=dict)
    speed: common.Timing | None = None
    one_clip_s: float | None = None

    def v2v(self, sigma: float) -> float:
        return self.results[sigma].v2v_cm


@dataclass
class CurvePoint:
    """A point of Figure 1: s/frame and V2V (cm) at the reference sigma."""

    label: str
    steps: int | None
    s_per_frame: float
    v2v_cm: float


@dataclass
class TableResult:
    """split: the corpus split the clips come from; tuned_on: where the filters were tuned
    ("val" clips, or "the same clips")."""

    settings: TableSettings
    rows: list[RowResult]
    tuning: FilterTuning
    curve: list[CurvePoint]
    num_clips: int
    clip_frames: int
    split: str = "test"
    tuned_on: str = "val"

    def row(self, name: str) -> RowResult:
        return next(r for r in self.rows if r.name == name)

    @property
    def best_filter(self) -> RowResult:
        ref = self.settings.reference_sigma
        return min((self.row(n) for n in FILTER_ROWS), key=lambda r: r.v2v(ref))

    def to_dict(self) -> dict:
        def results(r: RowResult) -> dict:
            return {f"{s:g}": e.to_dict() for s, e in r.results.items()}

        return {
            "split": self.split,
            "tuned_on": self.tuned_on,
            "settings": asdict(self.settings),
            "num_clips": self.num_clips,
            "clip_frames": self.clip_frames,
            "tuning": {
                "noise_sigma": self.tuning.noise_sigma,
                "clips": self.tuning.clips,
                "observations_v2v": self.tuning.observations_v2v,
                "gaussian": {f"{k:g}": v for k, v in self.tuning.gaussian_scores.items()},
                "savgol": {f"{w},{p}": v for (w, p), v in self.tuning.savgol_scores.items()},
            },
            "rows": [
                {
                    "name": r.name,
                    "params": r.params,
                    "results": results(r),
                    "speed": None if r.speed is None else asdict(r.speed),
                    "one_clip_s": r.one_clip_s,
                }
                for r in self.rows
            ],
            "curve": [asdict(p) for p in self.curve],
        }
