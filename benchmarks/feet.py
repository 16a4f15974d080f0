"""Benchmark: feet and floor with ``mdvae denoise --feet lock`` against ``--feet off``.

Held-out clips (60 frames at 30 Hz) of each split get Pose-NDF noise of each sigma
(``common.add_noise``, seed fixed per clip and sigma), are denoised the default way (forward
pass, closed-form offset and guard, as ``mdvae denoise`` runs on mocap) and then foot-locked
(``infer.feet.lock_feet``, with the noisy clip as the input, as ``mdvae denoise`` does).
Printed: issue 29's targets per split (V2V lock vs off, skate against the truth's, stance knee
error, the lock's time per frame on the clips and on one long take); per split, V2V, foot
skate, sliding share, penetration, float and joint acceleration of the ground truth,
``--feet off`` and ``--feet lock`` (``mdvae eval``'s definitions: scored on the ground truth's
contacts and floor), issue 20's targets, how well the contacts the lock finds match the ground
truth's, the lock's time.

    python benchmarks/feet.py [--corpus data/corpus] [--split test,unseen_test]
        [--max-clips N] [--sigmas 0,0.05,0.1,0.15,0.2] [--long-frames 18000]
        [--out docs/benchmarks.md]
    python benchmarks/feet.py --split unseen_val --variant keep=0 --variant speed_tol=0.7 ...

With ``--variant`` (repeatable: ``FootLockConfig`` fields as ``name=value,name=value``, or
``input=0`` for no input), only a compact comparison of those settings with the defaults and
``--feet off`` is printed (the design choices in docs/model.md, "Feet and floor", were made so
on the val and unseen_val splits).
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
from mdvae_cli.infer.feet import (
    FootLockConfig,
    detect_contacts,
    feet_of,
    for_noise,
    input_trust,
    lock_feet,
)
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
    split: str = ""
    knee_off: tuple[float, float] = (0.0, 0.0)  # stance knee error (deg), share held straight
    knee_lock: tuple[float, float] = (0.0, 0.0)
    long_take: tuple[int, float] | None = None  # (frames, seconds) of the lock on one long take


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


def contacts_found(
    motions: Sequence[Motion],
    body: BodyModel,
    cfg: FootLockConfig,
    sources: Sequence[Motion] | None = None,
) -> list:
    """The contacts the lock would find on each motion (with ``sources``, its settings for
    each source's noise, as :func:`lock_feet` does).  -> list of (T, 4) bool"""
    out = []
    for i, m in enumerate(motions):
        c = cfg
        if sources is not None:
            src = sources[i]
            c = for_noise(cfg, input_trust(src, LegModel.build(body, src.betas), cfg)[2])
        feet = feet_of(pose_legs(m, LegModel.build(body, m.betas))[0])
        out.append(detect_contacts(feet, m.fps, c))
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
    repeats: int = 3,
    long_frames: int = 0,
) -> SigmaResult:
    """Denoise the clips at one noise level, lock their feet, score both. Times: warm, the
    fastest of ``repeats`` runs; with ``long_frames``, the lock is also timed on one take of
    that many frames (the denoised clips end to end, the noisy ones as its input)."""
    gt = [c.motion for c in clips]
    noisy = common.add_noise(clips, sigma, seed)

    def denoise() -> list[Motion]:
        return denoise_default(noisy, denoiser, body)

    def lock(off: list[Motion]) -> list[Motion]:
        return [lock_feet(m, body, cfg, n) for m, n in zip(off, noisy, strict=True)]

    off = denoise()
    locked = lock(off)
    # timed warm, the fastest of a few runs (the machine may be shared)
    denoise_s = min(_seconds(denoise) for _ in range(repeats))
    lock_s = min(_seconds(lambda: lock(off)) for _ in range(repeats))
    long_take = None
    if long_frames:
        take, source = end_to_end(off, long_frames), end_to_end(noisy, long_frames)
        long_take = (take.num_frames, min(_seconds(lambda: lock_feet(take, body, cfg, source))
                                          for _ in range(repeats)))  # fmt: skip
    scores = common.evaluate_clips(gt, {"off": off, "lock": locked}, body)
    return SigmaResult(
        sigma=sigma,
        off=scores["off"],
        lock=scores["lock"],
        detection={
            "denoised motion (what `--feet lock` uses)": precision_recall(
                contacts_found(off, body, cfg, noisy), truth
            ),
            "noisy input, same settings": precision_recall(
                contacts_found(noisy, body, cfg, noisy), truth
            ),
        },
        denoise_s=denoise_s,
        lock_s=lock_s,
        frames=sum(m.num_frames for m in gt),
        knee_off=stance_knee_error(gt, off, body, truth),
        knee_lock=stance_knee_error(gt, locked, body, truth),
        long_take=long_take,
    )


def end_to_end(motions: Sequence[Motion], frames: int) -> Motion:
    """The motions one after another (repeated as needed) cut to ``frames`` frames, with the
    first one's shape and rate: a long take for timing."""
    reps = -(-frames // sum(m.num_frames for m in motions))
    seq = list(motions) * reps
    cat = lambda name: np.concatenate([getattr(m, name) for m in seq])[:frames]  # noqa: E731
    return Motion(root_orient=cat("root_orient"), pose_body=cat("pose_body"), trans=cat("trans"),
                  betas=motions[0].betas, fps=motions[0].fps)  # fmt: skip


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


def summary_table(by_split: dict[str, Sequence[SigmaResult]]) -> str:
    """Issue 29's targets, one row per split and noise level of TARGET_SIGMAS: V2V with and
    without the lock, skate against the truth's, stance knee error, the lock's time."""
    rows = []
    for split, results in by_split.items():
        for r in results:
            if not any(abs(r.sigma - s) < 1e-9 for s in TARGET_SIGMAS):
                continue
            off, lk = r.off, r.lock
            truth = lk.foot_skate_gt
            skate = "-" if not truth else (
                f"{off.foot_skate_pred / truth:.2f} / {lk.foot_skate_pred / truth:.2f}"
            )  # fmt: skip
            long = "-" if r.long_take is None else f"{1e3 * r.long_take[1] / r.long_take[0]:.4f}"
            rows.append([
                split, f"{r.sigma:.2f}", f"{off.v2v_cm:.3f} / {lk.v2v_cm:.3f}",
                f"{100 * (lk.v2v_cm / off.v2v_cm - 1):+.1f} %", skate,
                f"{r.knee_off[0]:.2f} / {r.knee_lock[0]:.2f}",
                f"{100 * r.knee_off[1]:.1f} / {100 * r.knee_lock[1]:.1f}",
                f"{1e3 * r.lock_s / r.frames:.3f}", long,
            ])  # fmt: skip
    header = ["split", "σ (rad)", "V2V off / lock (cm)", "lock vs off (target ≤ +1 %)",
              "skate / truth's, off / lock (target ≤ 1.3)",
              "stance knee error off / lock (°; target lock ≤ off)",
              "straight stance knees off / lock (%)", "lock ms/frame, 60-frame clips",
              "lock ms/frame, one long take"]  # fmt: skip
    return common.markdown_table(header, rows)


def split_markdown(split: str, results: Sequence[SigmaResult]) -> list[str]:
    """A split's detailed tables: metrics, issue 20's targets, contact detection, time."""
    cfg = FootLockConfig()
    frames = sum(r.frames for r in results)
    lock_s = sum(r.lock_s for r in results)
    den_s = sum(r.denoise_s for r in results)
    longs = [r.long_take for r in results if r.long_take is not None]
    long_line = ""
    if longs:
        n, sec = sum(x[0] for x in longs), sum(x[1] for x in longs)
        long_line = (
            f" On one long take ({longs[0][0]} frames: the split's denoised clips end to end, "
            f"the noisy ones as the input) the lock took {1e3 * sec / n:.4f} ms per frame "
            f"({n / sec:,.0f} frames/s)."
        )
    return [
        f"### {split}",
        "",
        metrics_table(results),
        "",
        "Issue 20's targets (ratios to the ground truth's value; the same for `--feet off` in "
        "brackets):",
        "",
        targets_table(results),
        "",
        f"Contacts the lock finds (its settings: smoothed {cfg.smooth_s:g} s, under "
        f"{100 * cfg.height_tol:g} cm above the joint's floor level and slower than "
        f"{cfg.speed_tol:g} m/s, going to {100 * cfg.noisy_height_tol:g} cm and "
        f"{cfg.noisy_speed_tol:g} m/s as the input's foot jitter goes from "
        f"{100 * cfg.noisy_from:g} to {100 * cfg.noisy_to:g} cm; cleaned and extended), "
        "precision / recall against the ground truth's (the shared rule: 5 cm, 0.2 m/s, "
        "unsmoothed):",
        "",
        detection_table(results),
        "",
        f"Time: the lock took {1e3 * lock_s / frames:.3f} ms per frame on the clips "
        f"({lock_s:.2f} s for {frames} frames, {1e3 * lock_s / frames * 60:.1f} ms per "
        f"60-frame clip), the denoising before it {1e3 * den_s / frames:.3f} ms per frame "
        f"(in process, warm, the fastest of a few runs, no file I/O).{long_line}",
        "",
    ]


def markdown(by_split: dict[str, Sequence[SigmaResult]], header: str) -> str:
    lines = [
        SECTION_BEGIN,
        "## Feet and floor (`mdvae denoise --feet lock`; `benchmarks/feet.py`)",
        "",
        header,
        "",
        "Issue 29's targets for the lock (σ 0.10-0.20; stance knees: legs whose foot is down "
        "in the ground truth, the bend between thigh and shank against the truth's; "
        "straight: under 2° where the truth bends over 5°):",
        "",
        summary_table(by_split),
        "",
    ]
    for split, results in by_split.items():
        lines += split_markdown(split, results)
    return "\n".join([*lines, SECTION_END]) + "\n"


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
    """A table: V2V, skate, penetration, float and stance knee error of ``--feet off``, the
    defaults and each variant."""
    gt = [c.motion for c in clips]
    truth = [
        contacts_of_feet(feet_of(pose_legs(m, LegModel.build(body, m.betas))[0]), m.fps) for m in gt
    ]
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
                     _f(g.penetration_gt, ".3f"), _f(g.float_gt, ".3f"), "-"])  # fmt: skip
        for name, e in scores.items():
            knee = stance_knee_error(gt, preds[name], body, truth)[0]
            rows.append([f"{sigma:.2f}", name, _f(e.v2v_cm, ".3f"), _f(e.foot_skate_pred),
                         _f(e.penetration_pred, ".3f"), _f(e.float_pred, ".3f"),
                         f"{knee:.2f}"])  # fmt: skip
    header = ["σ (rad)", "lock settings", "V2V (cm)", "foot skate (cm/s)", "penetration (cm)",
              "float (cm)", "stance knee error (°)"]  # fmt: skip
    return common.markdown_table(header, rows)


def main(argv: Sequence[str] | None = None) -> str:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "corpus")
    p.add_argument("--split", default="test,unseen_test", help="split names, comma-separated")
    p.add_argument("--max-clips", type=int, help="clips per split, spread evenly (default all)")
    p.add_argument("--sigmas", default=",".join(f"{s:g}" for s in SIGMAS))
    p.add_argument("--repeats", type=int, default=2, help="timed runs (the fastest is kept)")
    p.add_argument("--long-frames", type=int, default=18000,
                   help="frames of the long take the lock is also timed on (0: none)")  # fmt: skip
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--out", type=Path, help="markdown file to write the section into")
    p.add_argument("--variant", action="append", default=[], help="lock settings to compare")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    denoiser, _ = load_denoiser(args.denoiser)
    body = BodyModel(load_body_model(None))
    sigmas = [float(s) for s in args.sigmas.split(",") if s.strip()]
    splits = [s.strip() for s in args.split.split(",") if s.strip()]
    all_files = read_split(args.corpus / "split.json")
    by_split, described = {}, []
    for split in splits:
        files = all_files[split]
        clips = common.load_clips(files, args.corpus, 60, max_clips=args.max_clips)
        described.append(f"{len(clips)} from the {split} split ({len(files)} files)")
        if args.variant:
            table = compare_variants(clips, denoiser, body, sigmas, args.variant, args.seed)
            print(f"{len(clips)} clips of the {split} split, seed {args.seed}\n\n{table}")
            continue
        cfg = FootLockConfig()
        truth = [
            contacts_of_feet(feet_of(pose_legs(c.motion, LegModel.build(body, c.motion.betas))[0]),
                             c.motion.fps)
            for c in clips
        ]  # fmt: skip
        by_split[split] = [
            run_sigma(clips, denoiser, body, s, cfg, truth, args.seed, args.repeats,
                      args.long_frames if s == max(sigmas) else 0)
            for s in sigmas
        ]  # fmt: skip
        for r in by_split[split]:
            print(f"{split} σ={r.sigma:.2f}: V2V off {r.off.v2v_cm:.3f} lock {r.lock.v2v_cm:.3f}, "
                  f"knee {r.knee_off[0]:.2f} / {r.knee_lock[0]:.2f}", flush=True)  # fmt: skip
    if args.variant:
        return ""
    command = "python benchmarks/feet.py" + "".join(
        f" {a}" for a in (argv if argv is not None else __import__("sys").argv[1:])
    )
    header = (
        f"Clips of 60 frames (30 Hz): {'; '.join(described)}. Pose-NDF noise (seed "
        f"{args.seed}), shipped weights, built-in "
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
    md = markdown(by_split, header)
    print(md)
    if args.out is not None:
        common.write_section(args.out, md, SECTION_BEGIN, SECTION_END)
    return md


if __name__ == "__main__":
    main()
