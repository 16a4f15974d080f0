"""Motion-DVAE paper Table 1 and Figure 1 on held-out CMU subjects.

    python benchmarks/denoise_table.py [--corpus data/cmu_amass] [--out docs/benchmarks.md]
                                       [--max-clips N] [--quick]

Protocol. The test-split files (resampled to 30 Hz) are cut into non-overlapping 60-frame
(2 s) clips. Pose-NDF noise of sigma = 0.10, 0.15 and 0.20 rad is added to every clip, with a
seed fixed per clip and sigma. Every method then runs file to file on the noisy clips, and the
timed part is loading, denoising and saving all of them in one run:

* ground truth and observations (the noisy input), for reference;
* a Gaussian and a Savitzky-Golay filter (``mdvae_cli.filters``). Their parameters are tuned by
  grid search on clips of the val split at sigma = 0.15, for the lowest V2V;
* regression mode: one forward pass of the denoiser;
* optimisation mode: for each sigma, a copy of the denoiser is fine-tuned for 50 steps on all
  the test clips of that sigma at once, which then predicts them (the paper's protocol);
* refinement (``mdvae denoise --refine 50``): regression mode, then 50 gradient steps on each
  window's own latents, with a slow rotation offset (``mdvae_cli.infer.refine``).

The metrics are root-relative V2V (cm) and the mean joint acceleration (m/s^2; the ground truth
row gives the target value), frame-weighted over all clips. Speed is s/frame and frames/s of the
file-to-file run at sigma = 0.15, plus, for the filters and regression mode, one clip processed
alone after a warm-up. Figure 1 plots V2V against s/frame at sigma = 0.15 for 0, 20, 50, 100
and 250 optimisation steps, with the filters as reference points (matplotlib, optional).

The table, the machine description and the plot link go into a marked section of ``--out``
(other content of that file is kept). ``--quick`` runs a small subset to check that everything
works. Its numbers mean little, and it writes ``--out`` only when that is given explicitly.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/denoise_table.py
    import common  # type: ignore[no-redef]

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_filter_motion, savgol_filter_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.metrics import EvalResult
from mdvae_cli.model.denoiser import Denoiser
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
ROW_OFFSET = "Regression + offset (default)"
ROW_OPTIMIZATION_OFFSET = "Optimization + offset"
ROW_REFINE = "Latent refinement"
ROW_REGRESSION_MIRROR = "Regression + mirror"
ROW_REFINE_MIRROR = "Latent refinement + mirror"
ROWS = (
    ROW_GT, ROW_OBS, ROW_GAUSSIAN, ROW_SAVGOL, ROW_REGRESSION, ROW_REGRESSION_MIRROR, ROW_OFFSET,
    ROW_OPTIMIZATION, ROW_OPTIMIZATION_OFFSET, ROW_REFINE, ROW_REFINE_MIRROR,
)  # fmt: skip
FILTER_ROWS = (ROW_GAUSSIAN, ROW_SAVGOL)

SECTION_BEGIN = "<!-- denoise_table:begin (written by benchmarks/denoise_table.py) -->"
SECTION_END = "<!-- denoise_table:end -->"

Process = Callable[[list[Motion]], list[Motion]]


@dataclass
class TableSettings:
    """What the table is computed with (saved in the report).

    sigmas: noise levels (rad); reference_sigma: one of them, the level for filter tuning,
    speeds, ratios and the plot; optimize_steps: optimisation-mode steps in the table;
    curve_steps: steps plotted (0 = regression mode); window/stride: denoiser windows (30 Hz
    frames); lr, batch_size, seed: optimisation mode (seed also fixes the noise);
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
    batch_size: int = 64
    seed: int = 0
    refine_steps: int = RefineConfig.steps
    refine_lr: float = 0.1
    refine_offset: float = RefineConfig.offset_std
    single_clip_repeats: int = 5


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
    settings: TableSettings
    rows: list[RowResult]
    tuning: FilterTuning
    curve: list[CurvePoint]
    num_clips: int
    clip_frames: int

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


# --------------------------------------------------------------------------------------------
# computing the table


def _no_log(message: str) -> None:
    pass


def tune_filters(
    val_clips: Sequence[common.Clip], body: BodyModel, settings: TableSettings, log=_no_log
) -> FilterTuning:
    """Grid-search the filters on noisy val clips (reference sigma) for the lowest V2V."""
    gt = [c.motion for c in val_clips]
    noisy = common.add_noise(val_clips, settings.reference_sigma, settings.seed)
    candidates: dict = {"obs": noisy}
    for s in settings.gaussian_grid:
        candidates[("gaussian", s)] = common.LazyMap(
            lambda m, s=s: gaussian_filter_motion(m, s), noisy
        )
    for w, p in settings.savgol_grid:
        candidates[("savgol", (w, p))] = common.LazyMap(
            lambda m, w=w, p=p: savgol_filter_motion(m, w, p), noisy
        )
    log(f"tuning filters: {len(candidates) - 1} settings on {len(val_clips)} val clips")
    scores = {k: r.v2v_cm for k, r in common.evaluate_clips(gt, candidates, body).items()}
    return FilterTuning(
        noise_sigma=settings.reference_sigma,
        clips=len(val_clips),
        gaussian_scores={k[1]: v for k, v in scores.items() if k[0] == "gaussian"},
        savgol_scores={k[1]: v for k, v in scores.items() if k[0] == "savgol"},
        observations_v2v=scores["obs"],
    )


def _per_clip(fn: Callable[[Motion], Motion]) -> Process:
    return lambda motions: [fn(m) for m in motions]


def _denoise(
    denoiser: Denoiser,
    body: BodyModel,
    s: TableSettings,
    steps: int,
    refine: int | None = None,
    mirror: bool = False,
) -> Process:
    """Regression (steps 0) or optimisation mode; ``refine``: None = no refinement, 0 = the
    closed-form offset alone, N = N refinement steps (with the offset); ``mirror``: average
    with the mirror image's result (``mdvae denoise --mirror``)."""
    cfg = None
    if refine is not None:
        cfg = RefineConfig(steps=refine, lr=s.refine_lr, offset_std=s.refine_offset)

    def process(motions: list[Motion]) -> list[Motion]:
        # optimisation mode fine-tunes the networks it is given: always a fresh copy
        model = copy.deepcopy(denoiser) if steps else denoiser
        return denoise_motions(
            motions, model, body, s.window, s.stride, steps, s.lr, s.batch_size, s.seed,
            refine=cfg, mirror=mirror,
        )  # fmt: skip

    return process


def build_table(
    test_clips: Sequence[common.Clip],
    val_clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    settings: TableSettings,
    workdir: Path,
    log: Callable[[str], None] = _no_log,
) -> TableResult:
    """Run every method on every noise level and collect the table and the curve.

    test_clips, val_clips: clips at 30 Hz, all of the same length; workdir: an empty folder for
    the noisy and denoised files (emptied again as it goes).
    """
    if not test_clips or not val_clips:
        raise ValueError("need at least one test clip and one val clip")
    if settings.reference_sigma not in settings.sigmas:
        raise ValueError(f"reference sigma {settings.reference_sigma:g} is not among the sigmas")
    s = settings
    tuning = tune_filters(val_clips, body, s, log)
    g_sigma, (sg_w, sg_p) = tuning.gaussian_sigma, tuning.savgol
    log(f"tuned: Gaussian sigma {g_sigma:g} frames; Savitzky-Golay window {sg_w}, order {sg_p}")
    methods: dict[str, tuple[str, Process]] = {
        ROW_GAUSSIAN: (
            f"σ = {g_sigma:g} frames",
            _per_clip(lambda m: gaussian_filter_motion(m, g_sigma)),
        ),
        ROW_SAVGOL: (
            f"window {sg_w}, order {sg_p}",
            _per_clip(lambda m: savgol_filter_motion(m, sg_w, sg_p)),
        ),
        ROW_REGRESSION: (
            "one forward pass (the paper's; `--no-offset`)",
            _denoise(denoiser, body, s, 0),
        ),
        ROW_REGRESSION_MIRROR: (
            "one forward pass on the clip and on its mirror image, averaged",
            _denoise(denoiser, body, s, 0, mirror=True),
        ),
        ROW_OFFSET: (
            f"one forward pass + closed-form slow offsets {s.refine_offset:g} rad, "
            f"{RefineConfig.trans_offset_std:g} m on the root (`mdvae denoise`)",
            _denoise(denoiser, body, s, 0, 0),
        ),
        ROW_OPTIMIZATION: (
            f"{s.optimize_steps} steps on each sigma's set, lr {s.lr:g}, batch {s.batch_size}",
            _denoise(denoiser, body, s, s.optimize_steps),
        ),
        ROW_OPTIMIZATION_OFFSET: (
            f"optimization mode, then the slow offset (`--optimize {s.optimize_steps}`)",
            _denoise(denoiser, body, s, s.optimize_steps, 0),
        ),
        ROW_REFINE: (
            f"regression + {s.refine_steps} steps per window, lr {s.refine_lr:g}, "
            f"slow offset {s.refine_offset:g} rad",
            _denoise(denoiser, body, s, 0, s.refine_steps),
        ),
        ROW_REFINE_MIRROR: (
            "latent refinement on the clip and on its mirror image, averaged",
            _denoise(denoiser, body, s, 0, s.refine_steps, mirror=True),
        ),
    }
    rows = {ROW_GT: RowResult(ROW_GT), ROW_OBS: RowResult(ROW_OBS)}
    rows.update({name: RowResult(name, params) for name, (params, _) in methods.items()})
    extra_steps = [n for n in s.curve_steps if n not in (0, s.optimize_steps)]
    extra: dict[int, tuple[EvalResult, common.Timing]] = {}
    gt = [c.motion for c in test_clips]

    for sigma in s.sigmas:
        noisy = common.add_noise(test_clips, sigma, s.seed)
        folder = workdir / f"sigma_{sigma:g}"
        files = common.write_motions(noisy, folder / "noisy")
        predictions: dict = {ROW_OBS: noisy}
        timings: dict = {}
        runs: list[tuple[object, Process]] = [(n, p) for n, (_, p) in methods.items()]
        if sigma == s.reference_sigma:
            runs += [(n, _denoise(denoiser, body, s, n)) for n in extra_steps]
        for key, process in runs:
            log(f"sigma {sigma:g}: {key if isinstance(key, str) else f'{key} steps'}")
            outs, timings[key] = common.file_to_file(files, folder / "out", process)
            predictions[key] = [common.compact(o, g) for o, g in zip(outs, gt, strict=True)]
            shutil.rmtree(folder / "out")
        if sigma == s.reference_sigma:
            for name in (
                ROW_GAUSSIAN,
                ROW_SAVGOL,
                ROW_REGRESSION,
                ROW_REGRESSION_MIRROR,
                ROW_OFFSET,
            ):
                out = folder / "one"
                rows[name].one_clip_s = common.warm_median_seconds(
                    lambda p=methods[name][1], out=out, one=files[:1]: common.file_to_file(
                        one, out, p
                    ),
                    s.single_clip_repeats,
                )
        log(f"sigma {sigma:g}: evaluating {len(predictions)} sets of {len(gt)} clips")
        evaluated = common.evaluate_clips(gt, predictions, body)
        obs = evaluated[ROW_OBS]
        rows[ROW_GT].results[sigma] = replace(
            obs, v2v_cm=0.0, v2v_abs_cm=0.0, mpjpe_cm=0.0, accel_pred=obs.accel_gt, accel_error=0.0
        )
        for key, result in evaluated.items():
            if isinstance(key, int):
                extra[key] = (result, timings[key])
            else:
                rows[key].results[sigma] = result
                if sigma == s.reference_sigma and key in timings:
                    rows[key].speed = timings[key]
        shutil.rmtree(folder)

    ref = s.reference_sigma
    curve = []
    for n in s.curve_steps:
        if n in extra:
            result, timing = extra[n]
        else:
            row = rows[ROW_REGRESSION if n == 0 else ROW_OPTIMIZATION]
            result, timing = row.results[ref], row.speed
        curve.append(CurvePoint(f"{n} steps", n, timing.s_per_frame, result.v2v_cm))
    for name in (
        *FILTER_ROWS,
        ROW_OFFSET,
        ROW_OPTIMIZATION_OFFSET,
        ROW_REFINE,
        ROW_REGRESSION_MIRROR,
        ROW_REFINE_MIRROR,
    ):
        r = rows[name]
        curve.append(CurvePoint(name, None, r.speed.s_per_frame, r.v2v(ref)))
    return TableResult(
        settings=s,
        rows=[rows[n] for n in ROWS],
        tuning=tuning,
        curve=curve,
        num_clips=len(test_clips),
        clip_frames=test_clips[0].motion.num_frames,
    )


# --------------------------------------------------------------------------------------------
# rendering


def table_columns(settings: TableSettings) -> list[str]:
    """Header cells of the table, in order."""
    ref = f"{settings.reference_sigma:.2f}"
    return [
        "Method",
        "Parameters",
        "s/frame ↓",
        "frames/s ↑",
        "1 clip, warm (ms)",
        *(f"V2V σ={s:.2f} (cm) ↓" for s in settings.sigmas),
        *(f"Accel σ={s:.2f} (m/s²)" for s in settings.sigmas),
        f"absolute V2V σ={ref} (cm)",
        f"V2V / V2V(obs) σ={ref}",
        f"improvement over best filter σ={' / '.join(f'{x:.2f}' for x in settings.sigmas)}",
    ]


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def table_rows(result: TableResult) -> list[list[str]]:
    """The table's body cells, one list per row (same order as :func:`table_columns`)."""
    s = result.settings
    ref = s.reference_sigma
    obs = result.row(ROW_OBS).v2v(ref)
    best = result.best_filter
    out = []
    for r in result.rows:
        gt_row = r.name == ROW_GT
        accel = [r.results[x].accel_pred for x in s.sigmas]
        absolute = None if gt_row else r.results[ref].v2v_abs_cm
        if gt_row:
            v2v, ratio, gain = [None] * len(s.sigmas), "-", "-"
        else:
            v2v = [r.v2v(x) for x in s.sigmas]
            ratio = _num(r.v2v(ref) / obs if obs > 0 else None, ".3f")
            gains = (100 * (1 - r.v2v(x) / best.v2v(x)) for x in s.sigmas)
            gain = "best filter" if r is best else " / ".join(f"{g:+.1f} %" for g in gains)
        out.append(
            [
                r.name,
                r.params or "-",
                _num(r.speed.s_per_frame if r.speed else None, ".3g"),
                _num(r.speed.frames_per_s if r.speed else None, ",.0f"),
                _num(None if r.one_clip_s is None else 1000 * r.one_clip_s, ".3g"),
                *(_num(v, ".2f") for v in v2v),
                *(_num(a, ".2f") for a in accel),
                _num(absolute, ".2f"),
                ratio,
                gain,
            ]
        )
    return out


def tuning_markdown(t: FilterTuning) -> str:
    """The val grid as two small tables (V2V in cm)."""
    gauss = common.markdown_table(
        ["Gaussian σ (frames)", *(f"{k:g}" for k in t.gaussian_scores)],
        [["V2V (cm)", *(f"{v:.2f}" for v in t.gaussian_scores.values())]],
    )
    windows = sorted({w for w, _ in t.savgol_scores})
    orders = sorted({p for _, p in t.savgol_scores})
    sg = common.markdown_table(
        ["S-G window \\ order", *(str(p) for p in orders)],
        [[str(w), *(_num(t.savgol_scores.get((w, p)), ".2f") for p in orders)] for w in windows],
    )
    return gauss + "\n\n" + sg


def report_markdown(
    result: TableResult,
    machine: dict[str, str],
    context: dict[str, str],
    plot_link: str | None,
) -> str:
    """The whole section for docs/benchmarks.md (between the section markers)."""
    s, t = result.settings, result.tuning
    ref = f"{s.reference_sigma:.2f}"
    gw, (sw, sp) = t.gaussian_sigma, t.savgol
    lines = [
        SECTION_BEGIN,
        "## Denoising noisy mocap (paper Table 1 and Figure 1)",
        "",
        f"{result.num_clips} clips of {result.clip_frames} frames (30 Hz) from the test split, "
        f"Pose-NDF noise σ = {', '.join(f'{x:.2f}' for x in s.sigmas)} rad on the body joints "
        f"(seed {s.seed}). V2V is root-relative (cm), as in the paper; the absolute V2V "
        "keeps the root translation in (the noise leaves it clean: a method that moves it "
        "pays here). The acceleration is the mean joint "
        "acceleration (m/s²; the closer to the ground truth the better). Speed is measured file "
        f"to file at σ = {ref}: loading, denoising and saving all clips in one run; "
        "'1 clip, warm' is one clip processed alone after a warm-up (median). The last two "
        f"columns compare V2V with the observations' (at σ = {ref}) and with the better filter's "
        f"(the one tuned at σ = {ref}; at every σ; positive = lower error).",
        "",
        common.markdown_table(table_columns(s), table_rows(result)),
        "",
        f"Filters tuned on {t.clips} val clips at σ = {t.noise_sigma:.2f} (lowest V2V; "
        f"observations {t.observations_v2v:.2f} cm): Gaussian σ = {gw:g} frames, "
        f"Savitzky-Golay window {sw} / order {sp}.",
        "",
        "<details><summary>Filter grid on the val split (V2V, cm)</summary>",
        "",
        tuning_markdown(t),
        "",
        "</details>",
        "",
    ]
    if plot_link:
        lines += [f"![V2V versus speed at σ = {ref}]({plot_link})", ""]
    curve = ", ".join(
        f"{p.steps}: {p.v2v_cm:.2f} cm @ {p.s_per_frame:.3g} s/frame"
        for p in result.curve
        if p.steps is not None
    )
    lines += [f"Optimisation steps (σ = {ref}): {curve}.", "", "Setup:", ""]
    lines += [f"- {k}: {v}" for k, v in context.items()]
    lines += [f"- {k}: {v}" for k, v in machine.items()]
    lines += ["", SECTION_END]
    return "\n".join(lines) + "\n"


def plot_speed_accuracy(result: TableResult, path: Path, fps: float = 30.0) -> bool:
    """Figure 1: V2V versus s/frame (log x) at the reference sigma. False without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    ref = result.settings.reference_sigma
    obs = result.row(ROW_OBS).v2v(ref)
    ours = [p for p in result.curve if p.steps is not None]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=150)
    ax.plot([p.s_per_frame for p in ours], [p.v2v_cm for p in ours], "o-", label="Motion-DVAE")
    for p in ours:
        ax.annotate(str(p.steps), (p.s_per_frame, p.v2v_cm), textcoords="offset points",
                    xytext=(4, 4), fontsize=8)  # fmt: skip
    for p, marker in zip([p for p in result.curve if p.steps is None], "sD^v<>P", strict=False):
        ax.plot([p.s_per_frame], [p.v2v_cm], marker, label=p.label)
    ax.axhline(obs, color="grey", ls="--", lw=1, label=f"observations ({obs:.1f} cm)")
    ax.axhline(obs * (2 / 3), color="tab:red", ls=":", lw=1, label="-33 % error")
    ax.axvline(10 / fps, color="tab:purple", ls=":", lw=1, label="10x slower than real time")
    ax.set_xscale("log")
    ax.set_xlabel("speed (s/frame, file to file, log scale)")
    ax.set_ylabel("V2V (cm)")
    ax.set_title(f"Accuracy versus speed, σ = {ref:.2f}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------------------------
# command line


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "cmu_amass")
    p.add_argument("--split", type=Path, help="split file (default: CORPUS/split.json)")
    p.add_argument(
        "--out",
        type=Path,
        help="markdown file to write the section into (default: docs/benchmarks.md; "
        "with --quick only when given)",
    )
    p.add_argument("--plot", type=Path, help="PNG (default: denoise_speed_accuracy.png by --out)")
    p.add_argument("--json", type=Path, help="also write the raw numbers here")
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--body-model", type=Path, help="SMPL-family file (default: built-in body)")
    p.add_argument("--max-files", type=int, help="use at most this many files per split")
    p.add_argument("--max-clips", type=int, help="test clips to use, spread evenly (default all)")
    p.add_argument("--tune-clips", type=int, default=100, help="val clips for the filter grid")
    p.add_argument("--clip-frames", type=int, default=60, help="frames per clip (2 s at 30 Hz)")
    p.add_argument("--optimize-steps", type=int, default=50)
    p.add_argument("--curve-steps", default=",".join(map(str, CURVE_STEPS)))
    p.add_argument(
        "--refine-steps", type=int, default=RefineConfig.steps, help="steps of the refinement row"
    )
    p.add_argument(
        "--refine-offset",
        type=float,
        default=RefineConfig.offset_std,
        help="slow-offset scale of the refinement row",
    )
    p.add_argument("--threads", type=int, default=2, help="torch threads (the product's target)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workdir", type=Path, help="scratch folder (default: a temporary one)")
    p.add_argument("--quick", action="store_true", help="a small subset, to check the script")
    return p.parse_args(argv)


def settings_from_args(args: argparse.Namespace, window: int) -> TableSettings:
    s = TableSettings(
        optimize_steps=args.optimize_steps,
        curve_steps=tuple(int(x) for x in str(args.curve_steps).split(",") if x.strip()),
        window=window,
        stride=max(1, window * 3 // 4),
        seed=args.seed,
        refine_steps=args.refine_steps,
        refine_offset=args.refine_offset,
    )
    if args.quick:
        s.refine_steps = min(s.refine_steps, 10)
        s.gaussian_grid = (1.0, 2.0, 3.0)
        s.savgol_grid = ((7, 2), (11, 2), (15, 3))
        s.curve_steps = tuple(n for n in s.curve_steps if n <= s.optimize_steps)
        s.single_clip_repeats = 2
    return s


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with an ``error:`` line when the inputs are missing."""
    command = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(command)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        return _run(args, command)
    finally:
        torch.set_num_threads(previous_threads)  # leave a calling process as it was


def _run(args: argparse.Namespace, command: list[str]) -> int:
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.errors import MdvaeError
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.train.corpus import read_split

    if args.quick:
        args.max_files = args.max_files or 6
        args.max_clips = args.max_clips or 24
        args.tune_clips = min(args.tune_clips, 12)
    start = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - start:7.1f}s] {message}", file=sys.stderr, flush=True)

    try:
        split_file = args.split or args.corpus / "split.json"
        if not split_file.is_file():
            raise MdvaeError(f"no split file at {split_file} (is the corpus built?)")
        split = read_split(split_file)
        missing = [k for k in ("test", "val") if not split.get(k)]
        if missing:
            raise MdvaeError(f"{split_file}: no files in split(s) {', '.join(missing)}")
        denoiser, meta = load_denoiser(args.denoiser)
        window = int(meta.get("fit_config", {}).get("window", 60))
        body = BodyModel(load_body_model(args.body_model))
        root = split_file.parent
        test_files = common.pick_evenly(split["test"], args.max_files)
        val_files = common.pick_evenly(split["val"], args.max_files)
        log(f"loading {len(test_files)} test and {len(val_files)} val files")
        test = common.load_clips(test_files, root, args.clip_frames, max_clips=args.max_clips)
        val = common.load_clips(val_files, root, args.clip_frames, max_clips=args.tune_clips)
        if not test or not val:
            raise MdvaeError(f"no clip of {args.clip_frames} frames in the test or val files")
        settings = settings_from_args(args, window)
        with tempfile.TemporaryDirectory(prefix="mdvae-bench-") as tmp:
            work = args.workdir or Path(tmp)
            work.mkdir(parents=True, exist_ok=True)
            result = build_table(test, val, denoiser, body, settings, work, log)
    except MdvaeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    out = args.out if (args.out or args.quick) else REPO / "docs" / "benchmarks.md"
    context = {
        "corpus": f"{args.corpus} (split {split_file.name}: {len(test_files)} test files, "
        f"{len(val_files)} val files used)",
        "denoiser": str(args.denoiser or "shipped weights (mdvae_cli/weights/denoiser.npz)"),
        "body model": str(args.body_model or "built-in body"),
        "denoiser windows": f"{settings.window} frames, stride {settings.stride}",
        "run": "quick subset (--quick): numbers are only a smoke test"
        if args.quick
        else ("all test clips" if args.max_clips is None and args.max_files is None else "subset"),
        "command": " ".join(["python benchmarks/denoise_table.py", *command]),
        "benchmark time": f"{time.perf_counter() - start:.0f} s",
    }
    machine = common.machine_description()
    plot_link = None
    if out is not None:
        plot = args.plot or out.parent / "denoise_speed_accuracy.png"
        if plot_speed_accuracy(result, plot):
            plot_link = os.path.relpath(plot, out.parent)
        else:
            log("matplotlib is not installed: no plot (pip install matplotlib)")
        common.write_section(
            out, report_markdown(result, machine, context, plot_link), SECTION_BEGIN, SECTION_END
        )
        log(f"wrote {out}" + (f" and {plot}" if plot_link else ""))
    if args.json:
        payload = {**result.to_dict(), "machine": machine, "context": context}
        args.json.write_text(json.dumps(payload, indent=2) + "\n")
    print(common.markdown_table(table_columns(settings), table_rows(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
