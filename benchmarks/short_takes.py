"""Short takes: `mdvae denoise` against the best filter on clips of a few frames.

    python benchmarks/short_takes.py [--corpus data/corpus] [--split unseen_test]
                                     [--lengths 6,10,16,30,60] [--out docs/benchmarks.md]

Protocol. Files of a split (resampled to 30 Hz) are cut into non-overlapping clips of each
length; at most ``--max-clips`` per length, spread evenly over the files. Pose-NDF noise
(sigma = 0.10 / 0.15 / 0.20 rad, a seed per clip and sigma) is added; the default
(`mdvae denoise` as it runs: regression mode, the closed-form slow offset, the blend and the
foot lock) and every filter setting of a
grid run on them. The filter row is, per length and sigma, the grid's best setting *on those
very clips* (an oracle: it knows the answer it is scored on). Columns: V2V (cm, root-relative,
frame-weighted), the mean joint acceleration (m/s^2; the ground truth's beside it), the default's
gain over that filter, and how many clips came out further from the truth than their noisy
input was (per clip V2V) — the issue's "never worse than the input".

Also run by ``benchmarks/denoise_table.py`` (``--short-lengths``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_filter_motion, savgol_filter_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.metrics import mean_result
from mdvae_cli.model.denoiser import Denoiser

REPO = Path(__file__).resolve().parents[1]
LENGTHS = (6, 10, 16, 30, 60)
SIGMAS = (0.10, 0.15, 0.20)
GAUSSIAN_GRID = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
SAVGOL_GRID = ((5, 1), (7, 1), (9, 1), (11, 1), (15, 1), (7, 2), (11, 2), (15, 2))
SECTION_BEGIN = "<!-- short_takes:begin (written by benchmarks/short_takes.py) -->"
SECTION_END = "<!-- short_takes:end -->"


@dataclass
class ShortRow:
    """One length at one sigma: frame-weighted V2V and accelerations, the oracle filter."""

    length: int
    sigma: float
    clips: int
    noisy_v2v: float
    filter_name: str
    filter_v2v: float
    filter_accel: float
    default_v2v: float
    default_accel: float
    gt_accel: float
    worse_than_noisy: int
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def gain(self) -> float:
        """The default's V2V below the filter's, in % (positive = better than the filter)."""
        return 100.0 * (1.0 - self.default_v2v / self.filter_v2v)


def filter_grid(length: int) -> dict[str, Callable]:
    """Every filter setting that fits a clip of ``length`` frames, by name."""
    grid: dict[str, Callable] = {
        f"Gaussian σ={s:g}": (lambda m, s=s: gaussian_filter_motion(m, s)) for s in GAUSSIAN_GRID
    }
    for w, p in SAVGOL_GRID:
        if w <= length:
            grid[f"S-G {w}/{p}"] = lambda m, w=w, p=p: savgol_filter_motion(m, w, p)
    return grid


def short_take_rows(
    clips_by_length: dict[int, Sequence[common.Clip]],
    denoiser: Denoiser,
    body: BodyModel,
    sigmas: Sequence[float] = SIGMAS,
    seed: int = 0,
    settings: DenoiseSettings | None = None,
    log: Callable[[str], None] = lambda _: None,
) -> list[ShortRow]:
    """The rows of the short-take table (see the module docstring); ``settings``: what the
    default row runs (None: ``mdvae denoise``'s defaults)."""
    settings = settings or DenoiseSettings()
    rows = []
    for length, clips in clips_by_length.items():
        gt = [c.motion for c in clips]
        for sigma in sigmas:
            noisy = common.add_noise(clips, sigma, seed)
            default = denoise(noisy, settings, denoiser, body)
            preds: dict = {"noisy": noisy, "default": default}
            for name, fn in filter_grid(length).items():
                preds[name] = common.LazyMap(fn, noisy)
            per = common.evaluate_per_clip(gt, preds, body)
            means = {k: mean_result(v) for k, v in per.items()}
            best = min(filter_grid(length), key=lambda k: means[k].v2v_cm)
            worse = sum(
                d.v2v_cm > n.v2v_cm for d, n in zip(per["default"], per["noisy"], strict=True)
            )
            rows.append(
                ShortRow(length, sigma, len(clips), means["noisy"].v2v_cm, best,
                         means[best].v2v_cm, means[best].accel_pred, means["default"].v2v_cm,
                         means["default"].accel_pred, means["noisy"].accel_gt, int(worse))
            )  # fmt: skip
            r = rows[-1]
            log(f"{length} frames, σ {sigma:g}: default {r.default_v2v:.2f} cm, "
                f"{r.filter_name} {r.filter_v2v:.2f} ({r.gain:+.1f} %), worse {worse}")  # fmt: skip
    return rows


def short_takes_markdown(rows: Sequence[ShortRow], context: dict[str, str]) -> str:
    """The section for docs/benchmarks.md."""
    header = ["frames", "clips", "σ", "noisy V2V", "best filter (on these clips)",
              "filter V2V", "default V2V", "default vs filter", "accel GT / filter / default",
              "clips worse than noisy"]  # fmt: skip
    body = [
        [str(r.length), str(r.clips), f"{r.sigma:.2f}", f"{r.noisy_v2v:.2f}", r.filter_name,
         f"{r.filter_v2v:.2f}", f"{r.default_v2v:.2f}", f"{r.gain:+.1f} %",
         f"{r.gt_accel:.2f} / {r.filter_accel:.2f} / {r.default_accel:.2f}",
         str(r.worse_than_noisy)]
        for r in rows
    ]  # fmt: skip
    lines = [
        SECTION_BEGIN,
        "## Short takes",
        "",
        "Clips of a few frames (30 Hz) with Pose-NDF noise; V2V in cm (root-relative), joint "
        "acceleration in m/s². The filter is, per length and σ, the best of a Gaussian and "
        "Savitzky–Golay grid on the very clips it is scored on. 'Clips worse than noisy': "
        "clips whose denoised V2V is above their noisy input's.",
        "",
        common.markdown_table(header, body),
        "",
        "Setup:",
        "",
        *(f"- {k}: {v}" for k, v in context.items()),
        "",
        SECTION_END,
    ]
    return "\n".join(lines) + "\n"


def load_short_clips(
    files: Sequence[Path], root: Path, lengths: Sequence[int], max_clips: int | None
) -> dict[int, list[common.Clip]]:
    """Clips of each length from the files (at most ``max_clips`` each, spread evenly)."""
    return {n: common.load_clips(files, root, n, max_clips=max_clips) for n in lengths}


def main(argv: Sequence[str] | None = None) -> int:
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.train.corpus import read_split

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "corpus")
    p.add_argument("--split", default="unseen_test")
    p.add_argument("--lengths", default=",".join(map(str, LENGTHS)))
    p.add_argument("--max-clips", type=int, default=64, help="clips per length")
    p.add_argument("--denoiser", type=Path)
    p.add_argument("--out", type=Path, help="markdown file to write the section into")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    split_file = args.corpus / "split.json"
    if not split_file.is_file():
        print(f"error: no split file at {split_file} (is the corpus built?)", file=sys.stderr)
        return 2
    files = read_split(split_file).get(args.split, [])
    if not files:
        print(f"error: {split_file}: no files in split {args.split}", file=sys.stderr)
        return 2
    denoiser, _ = load_denoiser(args.denoiser)
    body = BodyModel(load_body_model(None))
    lengths = [int(x) for x in args.lengths.split(",") if x.strip()]
    clips = load_short_clips(files, split_file.parent, lengths, args.max_clips)

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - start:7.1f}s] {message}", file=sys.stderr, flush=True)

    rows = short_take_rows(clips, denoiser, body, seed=args.seed, log=log)
    context = {
        "split": f"{args.split} of {args.corpus}",
        "denoiser": str(args.denoiser or "shipped weights"),
        "command": " ".join(["python benchmarks/short_takes.py", *(argv or sys.argv[1:])]),
        "benchmark time": f"{time.perf_counter() - start:.0f} s",
        **{k: v for k, v in common.machine_description().items() if k in ("cpu", "date")},
    }
    text = short_takes_markdown(rows, context)
    if args.out:
        common.write_section(args.out, text, SECTION_BEGIN, SECTION_END)
    print(text)
    worst = np.mean([r.gain for r in rows]) if rows else float("nan")
    log(f"mean gain over the filter {worst:+.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
