"""Benchmark: denoising takes with spikes (outliers) as well as evenly spread noise.

Prints a markdown table of V2V (cm) and joint acceleration (m/s^2) on held-out clips, for
noise scenarios that add, on top of Pose-NDF noise, spikes of a given size on a fraction of
the joint-frames (a swapped marker, a solver flip), and for the methods a user would pick:
the tuned Savitzky-Golay filter (11 / 1, from ``denoise_table.py``), ``mdvae denoise`` (the
offset), ``--no-offset`` (the paper's regression mode), ``--refine 50`` and ``--refine 50
--outliers`` (Student-t noise per frame and joint, ``docs/model.md``, "Outliers").

    python benchmarks/outliers.py [--corpus data/corpus] [--split test] [--max-clips 32]
        [--out docs/benchmarks.md]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import savgol_filter_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import OUTLIER_DOF, RefineConfig
from mdvae_cli.model.denoiser import Denoiser, load_denoiser
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise, file_rng
from mdvae_cli.train.corpus import read_split

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
SECTION_BEGIN = "<!-- outliers:begin (written by benchmarks/outliers.py) -->"
SECTION_END = "<!-- outliers:end -->"


@dataclass(frozen=True)
class Scenario:
    """Pose-NDF noise ``sigma`` (rad) plus spikes N(0, spike_rad^2) per axis on ``spike_frac``
    of the (frame, body joint) entries."""

    sigma: float
    spike_frac: float = 0.0
    spike_rad: float = 0.0

    @property
    def label(self) -> str:
        if self.spike_frac == 0:
            return f"σ = {self.sigma:g}"
        return f"{self.spike_rad:g}-rad spikes on {self.spike_frac:.0%} + σ = {self.sigma:g}"


SCENARIOS = (
    Scenario(0.05, 0.02, 1.0),
    Scenario(0.05, 0.05, 0.5),
    Scenario(0.10),
    Scenario(0.15),
)


def noisy_clips(clips: Sequence[common.Clip], scenario: Scenario, seed: int) -> list[Motion]:
    """The scenario's noisy copies of the clips (seeded per clip name, as ``mdvae add-noise
    --sigma S --spike-frac F --spike-rad R`` seeds per file)."""
    return [
        add_pose_noise(
            c.motion,
            scenario.sigma,
            file_rng(seed, f"{c.name}@spikes"),
            spike_frac=scenario.spike_frac,
            spike_rad=scenario.spike_rad,
        )
        for c in clips
    ]


def methods(denoiser: Denoiser, body: BodyModel, steps: int) -> dict:
    """Name -> function(list of motions) -> list of motions."""
    refine = RefineConfig(steps=steps)
    robust = RefineConfig(steps=steps, outlier_dof=OUTLIER_DOF)
    return {
        "Savitzky-Golay 11/1": lambda ms: [savgol_filter_motion(m, 11, 1) for m in ms],
        "`mdvae denoise`": lambda ms: denoise_motions(
            ms, denoiser, body, refine=RefineConfig(steps=0)
        ),
        "`--no-offset`": lambda ms: denoise_motions(ms, denoiser, body),
        f"`--refine {steps}`": lambda ms: denoise_motions(ms, denoiser, body, refine=refine),
        f"`--refine {steps} --outliers`": lambda ms: denoise_motions(
            ms, denoiser, body, refine=robust
        ),
    }


def run(
    clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    scenarios: Sequence[Scenario] = SCENARIOS,
    steps: int = RefineConfig.steps,
    seed: int = 0,
) -> dict[str, dict[str, tuple[float, float]]]:
    """-> {scenario label: {method: (V2V cm, acceleration m/s^2)}}, with "Observations" and
    "Ground truth" (its acceleration) among the methods."""
    gt = [c.motion for c in clips]
    out = {}
    for sc in scenarios:
        noisy = noisy_clips(clips, sc, seed)
        preds = {"Observations": noisy}
        preds.update({name: f(noisy) for name, f in methods(denoiser, body, steps).items()})
        evaluated = common.evaluate_clips(gt, preds, body)
        row = {k: (r.v2v_cm, r.accel_pred) for k, r in evaluated.items()}
        row["Ground truth"] = (0.0, evaluated["Observations"].accel_gt)
        out[sc.label] = row
    return out


def markdown(result: dict[str, dict[str, tuple[float, float]]], header: str) -> str:
    """The table: one row per method, one column per scenario, 'V2V / accel' cells."""
    labels = list(result)
    names = ["Ground truth", *[n for n in next(iter(result.values())) if n != "Ground truth"]]
    rows = []
    for n in names:
        cells = []
        for lab in labels:
            v2v, acc = result[lab][n]
            cells.append(f"- / {acc:.2f}" if n == "Ground truth" else f"{v2v:.2f} / {acc:.2f}")
        rows.append([n, *cells])
    table = common.markdown_table(["V2V (cm) / accel (m/s²)", *labels], rows)
    title = "## Takes with spikes (`benchmarks/outliers.py`)"
    return f"{SECTION_BEGIN}\n{title}\n\n{header}\n\n{table}\n{SECTION_END}\n"


def main(argv: Sequence[str] | None = None) -> str:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "corpus")
    p.add_argument("--split", default="test")
    p.add_argument("--max-clips", type=int, default=32)
    p.add_argument("--steps", type=int, default=RefineConfig.steps, help="refinement steps")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--out", type=Path, help="markdown file to write the section into")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    files = common.pick_evenly(read_split(args.corpus / "split.json")[args.split], None)
    clips = common.load_clips(files, args.corpus, 60, max_clips=args.max_clips)
    denoiser, _ = load_denoiser(args.denoiser)
    body = BodyModel(load_body_model(None))
    result = run(clips, denoiser, body, steps=args.steps, seed=args.seed)
    header = (
        f"{len(clips)} clips of 60 frames (30 Hz) from the {args.split} split, shipped weights, "
        f"built-in body, seed {args.seed}; spikes are N(0, rad²) per axis on that fraction of "
        f"the (frame, body joint) entries, on top of Pose-NDF noise. Command: `python "
        f"benchmarks/outliers.py --split {args.split} --max-clips {args.max_clips}` "
        f"({time.perf_counter() - start:.0f} s)."
    )
    md = markdown(result, header)
    print(md)
    if args.out is not None:
        common.write_section(args.out, md, SECTION_BEGIN, SECTION_END)
    return md


if __name__ == "__main__":
    main()
