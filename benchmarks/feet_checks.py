"""Checks of the foot lock beyond ``benchmarks/feet.py``'s 30 Hz clips (docs/model.md, "Feet and
floor"): 120 Hz studio takes, and ankle twist on a long take.

    python benchmarks/feet_checks.py --part rates [--variant pin=0 ...]
    python benchmarks/feet_checks.py --part twist [--variant pin=0 ...]
    python benchmarks/feet_checks.py --part misses [--split unseen_test --sigma 0.1]

``rates``: every HDM05 squat and three takes of each of nine other HDM05 motions (120 Hz AMC,
``../shared/data/hdm05``) with Pose-NDF noise σ = 0.10 (``file_rng`` seed 0 by file name),
denoised as ``mdvae denoise --feet off`` does (blend, guard) and locked with the defaults and
each variant: V2V (cm) and foot skate (cm/s, the truth's in brackets), squats apart; and the
denoised feet's path (smoothed over 0.1 s) against the truth's in its contact frames, at the
take's rate and with truth and noisy take resampled to 30 Hz first (cm).

``twist``: a 10-minute take (the corpus files end to end at 30 Hz, σ = 0.10, seed 0), denoised
once; per lock setting, the angle between each ankle's world rotation with the lock and with
``--feet off``: frames over 20 and 45 degrees, the largest, the mean, and the mean against the
truth.

``misses``: where the skate of the lock (defaults) comes from on a split's 60-frame clips:
the truth's contact steps (a foot joint down at two frames) split by how the lock's own
contacts stand there (held at both frames; one or two frames from a held run; further), each
part's share of the mean skate (cm/s) and its mean speed, for the truth and the lock.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_smooth
from mdvae_cli.formats.registry import ReadOptions, read
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat
from mdvae_cli.infer.contact_runs import last_true, next_true
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig, lock_feet
from mdvae_cli.infer.input_kinds import refine_config
from mdvae_cli.infer.leg_ik import LegModel, feet_of, leg_chain, leg_rotations, pose_legs
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.contacts import contacts_of_feet
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise, file_rng
from mdvae_cli.motion.resample import resample_motion

try:
    from benchmarks import common
    from benchmarks.feet import contacts_found, denoise_default, parse_variant
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]
    from feet import contacts_found, denoise_default, parse_variant  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
HDM05 = REPO.parent / "shared" / "data" / "hdm05"
OTHERS = ("hopBothLegs", "kickLFront", "sneak2Steps", "jogLeftCircle", "elbowToKnee",
          "depositFloor", "grabHigh", "throwBasketball", "06-03")  # fmt: skip


def denoise(noisy: Motion, denoiser, body: BodyModel) -> Motion:
    """``mdvae denoise --feet off`` on a mocap take."""
    refine, _ = refine_config("mocap")
    return denoise_motions([noisy], denoiser, body, refine=refine, guard=True, blend=True)[0]


def path_error(truth: Motion, pred: Motion, body: BodyModel) -> float:
    """Mean distance (cm) of ``pred``'s horizontal foot-joint path, smoothed over 0.1 s, from
    the truth's, over the truth's contact frames."""
    legs = LegModel.build(body, truth.betas)
    ft, fp = (feet_of(pose_legs(m, legs)[0]) for m in (truth, pred))
    c = contacts_of_feet(ft, truth.fps)
    e = np.linalg.norm(gaussian_smooth(fp[..., :2] - ft[..., :2], 0.1 * truth.fps), axis=-1)
    return 100 * float(e[c].mean()) if c.any() else float("nan")


def rates(denoiser, body: BodyModel, variants: list[str]) -> None:
    files = sorted(HDM05.glob("*/*squat1Reps*.amc.gz"))
    for name in OTHERS:
        files += sorted(HDM05.glob(f"*/*{name}*.amc.gz"))[:3]
    rows: dict[str, list] = {}
    errors = []
    for path in files:
        truth = read(path, ReadOptions(body=body.data)).single()
        noisy = add_pose_noise(truth, 0.10, file_rng(0, path.name))
        off = denoise(noisy, denoiser, body)
        preds = {"off": [off]}
        for v in ["defaults", *variants]:
            cfg, _ = parse_variant("" if v == "defaults" else v)
            preds[v] = [lock_feet(off, body, cfg, noisy)]
        scores = common.evaluate_clips([truth], preds, body)
        for k, e in scores.items():
            rows.setdefault(k, []).append((e.v2v_cm, e.foot_skate_pred, e.foot_skate_gt))
        at30 = resample_motion(truth, 30.0)
        off30 = denoise(resample_motion(noisy, 30.0), denoiser, body)
        errors.append((path_error(truth, off, body), path_error(at30, off30, body)))
        print(f"{path.name}: " + ", ".join(f"{k} {e.v2v_cm:.2f}" for k, e in scores.items()),
              flush=True)  # fmt: skip
    squat = np.array(["squat" in p.name for p in files])
    for k, r in rows.items():
        a = np.array(r)
        print(f"{k}: squats ({squat.sum()}) V2V {a[squat, 0].mean():.3f} skate "
              f"{a[squat, 1].mean():.2f} ({a[squat, 2].mean():.2f}); others ({(~squat).sum()}) "
              f"V2V {a[~squat, 0].mean():.3f} skate {a[~squat, 1].mean():.2f} "
              f"({a[~squat, 2].mean():.2f})")  # fmt: skip
    e = np.nanmean(np.array(errors), axis=0)
    print(f"denoised foot path from the truth's in contact: {e[0]:.2f} cm at 120 Hz, "
          f"{e[1]:.2f} cm at 30 Hz")  # fmt: skip


def ankles(m: Motion, legs: LegModel) -> np.ndarray:
    """Each ankle's world rotation.  -> (T, 2, 3, 3)"""
    root = rotvec_to_rotmat(np.asarray(m.root_orient, dtype=np.float64))
    return leg_chain(root, leg_rotations(m), m.trans + legs.pelvis, legs.bones)[1][:, :, 2]


def degrees_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rotation matrices (..., 3, 3), degrees."""
    cos = (np.trace(a.swapaxes(-1, -2) @ b, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def twist(denoiser, body: BodyModel, variants: list[str]) -> None:
    corpus = REPO / "data" / "corpus"
    take = common.join_files(sorted(corpus.rglob("*.npz")), 10, 30.0)
    noisy = add_pose_noise(take, 0.10, np.random.default_rng(0))
    off = denoise(noisy, denoiser, body)
    legs = LegModel.build(body, off.betas)
    g_off, g_truth = ankles(off, legs), ankles(take, legs)
    apart = degrees_between(g_off, g_truth).mean()
    print(f"{off.num_frames} frames; --feet off: ankles {apart:.2f} deg from the truth's")
    for v in ["defaults", *variants]:
        cfg, _ = parse_variant("" if v == "defaults" else v)
        g = ankles(lock_feet(off, body, cfg, noisy), legs)
        a = degrees_between(g, g_off)
        print(f"{v}: ankle-frames over 45 deg from --feet off {(a > 45).sum()}, over 20 deg "
              f"{(a > 20).sum()}, largest {a.max():.1f}, mean {a.mean():.2f}; from the truth "
              f"{degrees_between(g, g_truth).mean():.2f}", flush=True)  # fmt: skip


def frames_from(c: np.ndarray) -> np.ndarray:
    """Each frame's distance in frames to the nearest True of its column (T, K) -> (T, K)"""
    t, T = np.arange(len(c))[:, None], len(c)
    before, after = last_true(c), next_true(c)
    return np.minimum(np.where(before >= 0, t - before, T), np.where(after < T, after - t, T))


def misses(denoiser, body: BodyModel, split: str, sigma: float) -> None:
    from mdvae_cli.train.corpus import read_split

    corpus = REPO / "data" / "corpus"
    clips = common.load_clips(read_split(corpus / "split.json")[split], corpus, 60)
    gt = [c.motion for c in clips]
    noisy = common.add_noise(clips, sigma, 0)
    off = denoise_default(noisy, denoiser, body)
    cfg = FootLockConfig()
    found = contacts_found(off, body, cfg, noisy)
    parts = ("held", "1-2 frames from a held run", "further")
    sums: dict[tuple[str, str], float] = {}
    count = 0
    for g, n, o, held in zip(gt, noisy, off, found, strict=True):
        legs = LegModel.build(body, g.betas)
        truth = contacts_of_feet(feet_of(pose_legs(g, legs)[0]), g.fps)
        step = truth[1:] & truth[:-1]
        near = frames_from(held)[1:]
        where = [held[1:] & held[:-1], ~(held[1:] & held[:-1]) & (near <= 2)]
        where.append(~where[0] & ~where[1])
        count += int(step.sum())
        for name, m in (("truth", g), ("lock", lock_feet(o, body, cfg, n))):
            f = feet_of(pose_legs(m, legs)[0])
            v = np.linalg.norm(np.diff(f[..., :2], axis=0), axis=-1) * m.fps
            for part, w in zip(parts, where, strict=True):
                sums[name, part] = sums.get((name, part), 0.0) + float(v[step & w].sum())
                if name == "truth":
                    sums["n", part] = sums.get(("n", part), 0.0) + float((step & w).sum())
    for part in parts:
        n = max(sums["n", part], 1)
        each = [
            f"{k} {100 * sums[k, part] / count:.2f} cm/s of the mean "
            f"({100 * sums[k, part] / n:.1f} cm/s there)"
            for k in ("truth", "lock")
        ]
        print(f"{part}: {100 * sums['n', part] / count:.1f} % of the truth's contact steps; "
              + ", ".join(each))  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=("rates", "twist", "misses"), required=True)
    p.add_argument("--split", default="unseen_test", help="misses: the split")
    p.add_argument("--sigma", type=float, default=0.1, help="misses: the noise")
    p.add_argument("--variant", action="append", default=[], help="lock settings to compare")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    denoiser, _ = load_denoiser(None)
    body = BodyModel(load_body_model(None))
    if args.part == "misses":
        misses(denoiser, body, args.split, args.sigma)
    else:
        (rates if args.part == "rates" else twist)(denoiser, body, args.variant)


if __name__ == "__main__":
    main()
