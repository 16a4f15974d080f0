"""Benchmark: feet and floor with ``mdvae denoise --feet lock`` against ``--feet off``.

Held-out clips (60 frames at 30 Hz) get Pose-NDF noise of each sigma (``common.add_noise``, seed
fixed per clip and sigma), are denoised the default way (forward pass, closed-form offset and
guard, as ``mdvae denoise`` runs on mocap) and then foot-locked (``infer.feet.lock_feet``, with
the noisy clip as the input, as ``mdvae denoise`` does). Printed: V2V, foot skate, sliding
share, penetration, float and joint acceleration of the ground truth, ``--feet off`` and
``--feet lock`` (``mdvae eval``'s definitions: scored on the ground truth's contacts and
floor); the targets of issue 20 at sigma 0.10-0.20; how well the contacts the lock finds match
the ground truth's; the lock's time.

    python benchmarks/feet.py [--corpus data/cmu_amass] [--split test] [--max-clips N]
        [--sigmas 0,0.05,0.1,0.15,0.2] [--out docs/benchmarks.md]
    python benchmarks/feet.py --split val --variant keep=0 --variant speed_tol=0.7 ...

With ``--variant`` (repeatable: ``FootLockConfig`` fields as ``name=value,name=value``, or
``input=0`` for no input), only a compact comparison of those settings with the defaults and
``--feet off`` is printed (the design choices in docs/model.md, "Feet and floor", were made so
on the val split).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig, detect_contacts, feet_of, lock_feet
from mdvae_cli.infer.input_kinds import refine_config
from mdvae_cli.infer.leg_ik import LegModel, pose_legs
from mdvae_cli.metrics import EvalResult
from mdvae_cli.model.denoiser import Denoiser, load_denoiser
from mdvae_cli.motion.contacts import contacts_of_feet, foot_of_joints
from mdvae_cli.motion.motion import Motion
from mdvae_cli.train.corpus import read_split

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
SECTION_BEGIN = "<!-- feet:begin (written by benchmarks/feet.py) -->"
SECTION_END = "<!-- feet:end -->"
SIGMAS = (0.0, 0.05, 0.10, 0.15, 0.20)
TARGET_SIGMAS = (0.10, 0.15, 0.20)


@dataclass
class SigmaResult:
    """One noise level: metrics of off / lock, contact detection scores, seconds spent."""

    sigma: float
    off: EvalResult
    lock: EvalResult
    detection: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (P, R)
    denoise_s: float = 0.0
    lock_s: float = 0.0
    frames: int = 0


def denoise_default(noisy: list[Motion], denoiser: Denoiser, body: BodyModel) -> list[Motion]:
    """``mdvae denoise --feet off`` on mocap: the forward pass, the offset, the guard."""
    refine, _ = refine_config("mocap")
    return denoise_motions(noisy, denoiser, body, refine=refine, guard=True)


def precision_recall(found: list[np.ndarray], truth: list[np.ndarray]) -> tuple[float, float]:
    """Pooled precision and recall of per-clip (T, 4) bool contact arrays."""
    tp = sum(int((f & t).sum()) for f, t in zip(found, truth, strict=True))
    fp = sum(int((f & ~t).sum()) for f, t in zip(found, truth, strict=True))
    fn = sum(int((~f & t).sum()) for f, t in zip(found, truth, strict=True))
    return tp / max(tp + fp, 1), tp / max(tp + fn, 1)


def contacts_found(motions: Sequence[Motion], body: BodyModel, cfg: FootLockConfig) -> list:
    """The contacts the lock would find on each motion.  -> list of (T, 4) bool"""
    out = []
    for m in motions:
        feet = feet_of(pose_legs(m, LegModel.build(body, m.betas))[0])
        out.append(detect_contacts(feet, m.fps, cfg))
    return out


def knee_bends(motion: Motion, body: BodyModel, betas: np.ndarray | None = None) -> np.ndarray:
    """Each knee's bend angle (0 = straight), degrees, from hip, knee and ankle as posed with the
    shape ``betas`` (default the motion's).  -> (T, 2) left, right"""
    pos = pose_legs(motion, LegModel.build(body, motion.betas if betas is None else betas))[0]
    thigh, shank = pos[:, :, 1] - pos[:, :, 0], pos[:, :, 2] - pos[:, :, 1]
    cos = (thigh * shank).sum(-1) / np.maximum(
        np.linalg.norm(thigh, axis=-1) * np.linalg.norm(shank, axis=-1), 1e-12
    )
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def stance_knee_error(
    gt: Sequence[Motion], pred: Sequence[Motion], body: BodyModel, truth: Sequence[np.ndarray]
) -> tuple[float, float]:
    """Knees of legs whose foot is down in the ground truth (``truth``: its (T, 4) contacts):
    the mean |bend angle - the truth's| (degrees), and the share of those knees held straight
    (bend under 2 degrees) where the truth's bends over 5.  -> (error, share)"""
    errors, straight = [], []
    for g, p, c in zip(gt, pred, truth, strict=True):
        down = foot_of_joints(c)
        bend_gt, bend = knee_bends(g, body)[down], knee_bends(p, body, g.betas)[down]
        errors.append(np.abs(bend - bend_gt))
        straight.append((bend < 2.0)[bend_gt > 5.0])
    e, s = np.concatenate(errors), np.concatenate(straight)
    return float(e.mean()) if e.size else 0.0, float(s.mean()) if s.size else 0.0


def _seconds(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def run_sigma(
    clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    sigma: float,
    cfg: FootLockConfig,
    truth: list[np.ndarray],
    seed: int = 0,
) -> SigmaResult:
    """Denoise the clips at one noise level, lock their feet, score both."""
    gt = [c.motion for c in clips]
    noisy = common.add_noise(clips, sigma, seed)

    def denoise() -> list[Motion]:
        return denoise_default(noisy, denoiser, body)

    def lock(off: list[Motion]) -> list[Motion]:
        return [lock_feet(m, body, cfg, n) for m, n in zip(off, noisy, strict=True)]

    off = denoise()
    locked = lock(off)
    # timed warm, the fastest of three runs (the machine may be shared)
    denoise_s = min(_seconds(denoise) for _ in range(3))
    lock_s = min(_seconds(lambda: lock(off)) for _ in range(3))
    scores = common.evaluate_clips(gt, {"off": off, "lock": locked}, body)
    return SigmaResult(
        sigma=sigma,
        off=scores["off"],
        lock=scores["lock"],
        detection={
            "denoised motion (what `--feet lock` uses)": precision_recall(
                contacts_found(off, body, cfg), truth
            ),
            "noisy input, same settings": precision_recall(contacts_found(noisy, body, cfg), truth),
        },
        denoise_s=denoise_s,
        lock_s=lock_s,
        frames=sum(m.num_frames for m in gt),
    )


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "-" if x is None else format(x, fmt)


def metrics_table(results: Sequence[SigmaResult]) -> str:
    """One row per noise level and method (ground truth, off, lock)."""
    rows = []
    for r in results:
        g = r.off  # the ground truth's own values ride along in every result
        rows.append([f"{r.sigma:.2f}", "ground truth", "-", _f(g.foot_skate_gt),
                     _f(g.foot_slide_gt, ".1f"), _f(g.penetration_gt, ".3f"),
                     _f(g.float_gt, ".3f"), _f(g.accel_gt)])  # fmt: skip
        for name, e in (("`--feet off`", r.off), ("`--feet lock`", r.lock)):
            rows.append([f"{r.sigma:.2f}", name, _f(e.v2v_cm, ".3f"), _f(e.foot_skate_pred),
                         _f(e.foot_slide_pred, ".1f"), _f(e.penetration_pred, ".3f"),
                         _f(e.float_pred, ".3f"), _f(e.accel_pred)])  # fmt: skip
    header = ["σ (rad)", "motion", "V2V (cm)", "foot skate (cm/s)", "sliding > 0.6 m/s (%)",
              "penetration (cm)", "float (cm)", "accel (m/s²)"]  # fmt: skip
    return common.markdown_table(header, rows)


def targets_table(results: Sequence[SigmaResult]) -> str:
    """Issue 20's targets: lock's skate and penetration against the ground truth's, V2V change."""

    def ratio(lock: float | None, off: float | None, truth: float | None) -> str:
        if lock is None or off is None or not truth:
            return "-"  # no contact, or a truth that never slides or sinks
        return f"{lock / truth:.2f} (off: {off / truth:.2f})"

    rows = []
    for r in results:
        if not any(abs(r.sigma - s) < 1e-9 for s in TARGET_SIGMAS):
            continue
        lk, off = r.lock, r.off
        rows.append([
            f"{r.sigma:.2f}",
            ratio(lk.foot_skate_pred, off.foot_skate_pred, lk.foot_skate_gt),
            ratio(lk.penetration_pred, off.penetration_pred, lk.penetration_gt),
            f"{100 * (lk.v2v_cm / off.v2v_cm - 1):+.1f} %" if off.v2v_cm else "-",
        ])  # fmt: skip
    header = [
        "σ (rad)",
        "skate / GT skate (target ≤ 1.10)",
        "penetration / GT penetration (target ≤ 1.10)",
        "V2V lock vs off (target ±1 %)",
    ]
    return common.markdown_table(header, rows)


def detection_table(results: Sequence[SigmaResult]) -> str:
    """Precision / recall of the lock's contacts against the ground truth's, per source."""
    names = list(results[0].detection)
    rows = [
        [name, *(f"{r.detection[name][0]:.2f} / {r.detection[name][1]:.2f}" for r in results)]
        for name in names
    ]
    header = ["contacts found on", *(f"σ = {r.sigma:.2f}" for r in results)]
    return common.markdown_table(header, rows)


def markdown(results: Sequence[SigmaResult], header: str) -> str:
    frames = sum(r.frames for r in results)
    lock_s = sum(r.lock_s for r in results)
    den_s = sum(r.denoise_s for r in results)
    lines = [
        SECTION_BEGIN,
        "## Feet and floor (`mdvae denoise --feet lock`; `benchmarks/feet.py`)",
        "",
        header,
        "",
        metrics_table(results),
        "",
        "Issue 20's targets (ratios to the ground truth's value; the same for `--feet off` in "
        "brackets):",
        "",
        targets_table(results),
        "",
        "Contacts the lock finds (its settings: smoothed 0.05 s, under 5 cm above the joint's "
        "floor level, slower than 1 m/s, cleaned and extended), precision / recall against the "
        "ground truth's (the shared rule: 5 cm, 0.2 m/s, unsmoothed):",
        "",
        detection_table(results),
        "",
        f"Time: the lock took {1e3 * lock_s / frames:.3f} ms per frame "
        f"({lock_s:.2f} s for {frames} frames, {1e3 * lock_s / frames * 60:.1f} ms per "
        f"60-frame clip), the denoising before it {1e3 * den_s / frames:.3f} ms per frame "
        "(in process, warm, the fastest of three runs, no file I/O).",
        "",
        SECTION_END,
    ]
    return "\n".join(lines) + "\n"


def parse_variant(text: str) -> tuple[FootLockConfig, bool]:
    """``"keep=0,speed_tol=0.7"`` -> (the config, whether the input is given to the lock)."""
    fields: dict[str, float] = {}
    use_input = True
    for item in filter(None, (x.strip() for x in text.split(","))):
        name, _, value = item.partition("=")
        if name == "input":
            use_input = value not in ("0", "false", "no")
        else:
            fields[name] = int(value) if name == "passes" else float(value)
    return FootLockConfig(**fields), use_input


def compare_variants(
    clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    sigmas: Sequence[float],
    variants: Sequence[str],
    seed: int = 0,
) -> str:
    """A table: V2V, skate, penetration, float of ``--feet off``, the defaults and each variant."""
    gt = [c.motion for c in clips]
    rows = []
    for sigma in sigmas:
        noisy = common.add_noise(clips, sigma, seed)
        off = denoise_default(noisy, denoiser, body)
        preds = {"`--feet off`": off}
        for text in ["defaults", *variants]:
            cfg, use_input = parse_variant("" if text == "defaults" else text)
            preds[text] = [
                lock_feet(m, body, cfg, n if use_input else None)
                for m, n in zip(off, noisy, strict=True)
            ]
        scores = common.evaluate_clips(gt, preds, body)
        g = scores["`--feet off`"]
        rows.append([f"{sigma:.2f}", "ground truth", "-", _f(g.foot_skate_gt),
                     _f(g.penetration_gt, ".3f"), _f(g.float_gt, ".3f")])  # fmt: skip
        for name, e in scores.items():
            rows.append([f"{sigma:.2f}", name, _f(e.v2v_cm, ".3f"), _f(e.foot_skate_pred),
                         _f(e.penetration_pred, ".3f"), _f(e.float_pred, ".3f")])  # fmt: skip
    header = ["σ (rad)", "lock settings", "V2V (cm)", "foot skate (cm/s)", "penetration (cm)",
              "float (cm)"]  # fmt: skip
    return common.markdown_table(header, rows)


def main(argv: Sequence[str] | None = None) -> str:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "cmu_amass")
    p.add_argument("--split", default="test")
    p.add_argument("--max-clips", type=int, help="clips to use, spread evenly (default all)")
    p.add_argument("--sigmas", default=",".join(f"{s:g}" for s in SIGMAS))
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--out", type=Path, help="markdown file to write the section into")
    p.add_argument("--variant", action="append", default=[], help="lock settings to compare")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    files = read_split(args.corpus / "split.json")[args.split]
    clips = common.load_clips(files, args.corpus, 60, max_clips=args.max_clips)
    denoiser, _ = load_denoiser(args.denoiser)
    body = BodyModel(load_body_model(None))
    sigmas = [float(s) for s in args.sigmas.split(",") if s.strip()]
    if args.variant:
        table = compare_variants(clips, denoiser, body, sigmas, args.variant, args.seed)
        print(f"{len(clips)} clips of the {args.split} split, seed {args.seed}\n\n{table}")
        return table
    cfg = FootLockConfig()
    truth = [
        contacts_of_feet(feet_of(pose_legs(c.motion, LegModel.build(body, c.motion.betas))[0]),
                         c.motion.fps)
        for c in clips
    ]  # fmt: skip
    results = [run_sigma(clips, denoiser, body, s, cfg, truth, args.seed) for s in sigmas]
    command = "python benchmarks/feet.py" + "".join(
        f" {a}" for a in (argv if argv is not None else __import__("sys").argv[1:])
    )
    header = (
        f"{len(clips)} clips of 60 frames (30 Hz) from the {args.split} split "
        f"({len(files)} files), Pose-NDF noise (seed {args.seed}), shipped weights, built-in "
        "body, default denoising (forward pass + closed-form offset + guard, `mdvae denoise "
        "--feet off`), then the lock with the noisy clip as its input. Foot metrics as `mdvae "
        "eval` computes them, on the ground truth's contacts (a foot joint under 5 cm above its "
        "floor level, the take's 2 % quantile of its height, and slower than 0.2 m/s) and "
        "floor (median lowest sole point there): skate = mean horizontal speed of contacting "
        "foot joints, sliding = share of those over 0.6 m/s (2 cm/frame at 30 Hz), "
        "penetration = mean depth of each foot's lowest sole point under the floor (all "
        "frames), float = its height above the floor while that foot is down. V2V is "
        f"root-relative. Command: `{command}`, {args.threads} torch threads "
        f"({time.perf_counter() - start:.0f} s; {common.cpu_model()})."
    )
    md = markdown(results, header)
    print(md)
    if args.out is not None:
        common.write_section(args.out, md, SECTION_BEGIN, SECTION_END)
    return md


if __name__ == "__main__":
    main()
