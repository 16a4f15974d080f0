"""Benchmark of a Motion-DVAE prior on held-out motion (issue: shipped prior quality).

Prints a markdown table:
* reconstruction V2V (cm, root-relative and absolute) of 60-frame windows through
  encoder -> decoder (posterior means), and the KL per step; the same after the encoder's
  latents are refined for ``--refine-steps`` Adam steps on each window's training loss
  (semi-amortised inference, ``mdvae_cli.train.reconstruct.refine_reconstruction``);
* 10-second prior samples started from real first frames: joint acceleration (m/s^2) vs real
  motion, the lowest foot height over the sample (drift through the floor) and the largest
  joint speed (exploding joints); raw prior samples, and (``--floor-particles``) samples
  conditioned on the real motion's floor as ``mdvae sample`` draws them by default.

    python benchmarks/prior.py [--prior PATH] [--corpus data/corpus] [--split test]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.sample import FOOT_JOINTS, PARTICLES, SPEED_LIMIT, sample_motion
from mdvae_cli.model.chunks import MODEL_FPS
from mdvae_cli.model.losses import gaussian_kl
from mdvae_cli.model.state import state_to_params
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.reconstruct import refine_reconstruction
from mdvae_cli.train.train_config import TrainConfig

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]


def reconstruction(
    prior, body, windows: WindowSet, batch: int = 256, train=None, steps: int = 0
) -> dict[str, float]:
    """Encoder -> decoder on windows (posterior means); V2V on the full mesh. With ``steps``,
    the encoder's latents are first refined for that many steps on each window's training
    loss (``train``: the run's TrainConfig; semi-amortised, ``infer.refine``)."""
    norm = prior.normalizer
    v2v, v2v_abs, kls, n = 0.0, 0.0, 0.0, 0
    for i in range(0, len(windows), batch):
        w = windows.subset(torch.arange(i, min(i + batch, len(windows))))
        x0n = norm.normalize(w.x0)
        x_mean, post = refine_reconstruction(prior, body, w, train, steps)
        with torch.no_grad():
            p = prior.dvae.prior(post.mean, x0n)
            kls += float(gaussian_kl(post.mean, post.logvar, p.mean, p.logvar).sum())
        B, T = w.x.shape[:2]
        betas = w.betas.repeat_interleave(T, 0)
        outs = []
        for x in (norm.denormalize(x_mean), w.x):
            q = state_to_params(x.reshape(B * T, -1))
            with torch.no_grad():
                outs.append(body(q.root_orient, q.pose_body, q.trans, betas, vertices=True))
        hat, gt = outs
        v2v_abs += float((hat.vertices - gt.vertices).norm(dim=-1).mean(-1).sum())
        rel_hat = hat.vertices - hat.joints[:, :1]
        rel_gt = gt.vertices - gt.joints[:, :1]
        v2v += float((rel_hat - rel_gt).norm(dim=-1).mean(-1).sum())
        n += B * T
    return {"v2v_cm": 100 * v2v / n, "v2v_abs_cm": 100 * v2v_abs / n, "kl_per_step": kls / n}


@torch.no_grad()
def samples(
    prior,
    body,
    files: list[Path],
    seconds: float,
    seed: int,
    temperature: float = 1.0,
    per_file: int = 1,
    particles: int = 0,
    speed_limit: float | None = None,
) -> dict[str, float]:
    """``per_file`` prior samples from each file's first frame vs the real motion of the same
    length (seeds seed, seed + 1, ... over all samples); ``particles`` > 0: conditioned on the
    real motion's floor and ``speed_limit`` (``mdvae sample``'s default) with that many
    particles."""
    frames = int(seconds * MODEL_FPS)
    acc_s, acc_r, min_feet, floor_real, max_speed = [], [], [], [], []
    for k, f in enumerate(files):
        real = resample_motion(load_motion(f), MODEL_FPS)
        jr = joints(body, real)
        a = (jr[:-2] - 2 * jr[1:-1] + jr[2:]) * MODEL_FPS**2
        acc_r.append(float(np.linalg.norm(a, axis=-1).mean()))
        floor = float(jr[:, FOOT_JOINTS, 2].min())
        cond = {"floor": floor, "particles": particles, "speed_limit": speed_limit}
        cond = cond if particles else {}
        for s in range(per_file):
            gen = sample_motion(
                prior, body, real, frames, seed=seed + k * per_file + s,
                temperature=temperature, **cond,
            )  # fmt: skip
            jg = joints(body, gen)
            a = (jg[:-2] - 2 * jg[1:-1] + jg[2:]) * MODEL_FPS**2
            acc_s.append(float(np.linalg.norm(a, axis=-1).mean()))
            floor_real.append(floor)
            min_feet.append(float(jg[:, FOOT_JOINTS, 2].min()) - floor)
            max_speed.append(float(np.linalg.norm(np.diff(jg, axis=0), axis=-1).max() * MODEL_FPS))
    return {
        "accel_samples": float(np.mean(acc_s)),
        "accel_real": float(np.mean(acc_r)),
        "lowest_foot_cm": 100 * float(np.min(min_feet)),
        "mean_lowest_foot_cm": 100 * float(np.mean(min_feet)),
        "max_joint_speed": float(np.max(max_speed)),
    }


def sample_table(title: str, smps: dict[float, dict[str, float]], temps: list[float]) -> None:
    """Print the sample figures of each temperature as a markdown table."""
    print(f"| {title}, temperature | " + " | ".join(f"{t:g}" for t in temps) + " |")
    print("|---|" + "---|" * len(temps))
    real = next(iter(smps.values()))["accel_real"]
    rows = [
        (f"joint acceleration (m/s²), real motion: {real:.2f}", "accel_samples", "%.2f"),
        ("lowest foot vs real floor, worst (cm)", "lowest_foot_cm", "%.1f"),
        ("lowest foot vs real floor, mean (cm)", "mean_lowest_foot_cm", "%.1f"),
        ("largest joint speed (m/s)", "max_joint_speed", "%.1f"),
    ]
    for label, key, fmt in rows:
        print(f"| {label} | " + " | ".join(fmt % smps[t][key] for t in temps) + " |")
    print(
        "| acceleration ratio samples / real | "
        + " | ".join(f"{smps[t]['accel_samples'] / real:.2f}" for t in temps)
        + " |"
    )


def joints(body, motion) -> np.ndarray:
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    out = body(t(motion.root_orient), t(motion.pose_body), t(motion.trans), t(motion.betas)[None])
    return out.joints.numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prior", default=None, help="prior checkpoint/run (default: shipped)")
    ap.add_argument("--corpus", default="data/corpus")
    ap.add_argument("--split", default="test")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--max-files", type=int, default=40)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--temperatures", default="1.0,0.5", help="prior sampling temperatures")
    ap.add_argument("--samples-per-file", type=int, default=1, help="prior samples per file")
    ap.add_argument(
        "--refine-steps",
        type=int,
        default=50,
        help="semi-amortised row: steps of the training loss per window from the encoder",
    )
    ap.add_argument(
        "--floor-particles",
        type=int,
        default=PARTICLES,
        help="also sample conditioned on the real floor and the speed limit with this many "
        "particles, as mdvae sample does (0 = not)",
    )
    ap.add_argument(
        "--speed-limit",
        type=float,
        default=SPEED_LIMIT,
        help="joint speed limit (m/s) of the conditioned samples (0 = none)",
    )
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    start = time.time()
    prior, meta, body, files, windows = common.prior_and_windows(
        args.prior, Path(args.corpus), args.split, args.max_files
    )
    rec = reconstruction(prior, body, windows)
    train = TrainConfig.from_dict(meta["train_config"])
    refined = reconstruction(prior, body, windows, train=train, steps=args.refine_steps)
    long_files = [f for f in files if load_motion(f).duration >= args.seconds]
    temps = [float(t) for t in args.temperatures.split(",")]
    smps = {
        t: samples(prior, body, long_files, args.seconds, 0, t, args.samples_per_file)
        for t in temps
    }
    floored = {
        t: samples(
            prior,
            body,
            long_files,
            args.seconds,
            0,
            t,
            args.samples_per_file,
            args.floor_particles,
            args.speed_limit or None,
        )  # fmt: skip
        for t in (temps if args.floor_particles else [])
    }
    print(
        f"Prior benchmark on the {args.split} split: {len(files)} files, {len(windows)} "
        f"windows of 60 frames, {len(long_files) * args.samples_per_file} samples of "
        f"{args.seconds:g} s from {len(long_files)} files "
        f"({platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{time.time() - start:.0f} s)\n"
    )
    print(
        "| reconstruction (posterior means) | encoder -> decoder | encoder + "
        f"{args.refine_steps} refinement steps -> decoder |\n|---|---|---|"
    )
    for label, key in (
        ("V2V, root-relative (cm)", "v2v_cm"),
        ("V2V, absolute (cm)", "v2v_abs_cm"),
        ("KL per step (nats)", "kl_per_step"),
    ):
        print(f"| {label} | {rec[key]:.2f} | {refined[key]:.2f} |")
    print()
    sample_table("prior samples", smps, temps)
    if floored:
        print()
        sample_table(
            f"samples kept on the floor and under {args.speed_limit:g} m/s "
            f"({args.floor_particles} particles)",
            floored,
            temps,
        )
    smp = {f"T{t:g}_{k}": v for t in temps for k, v in smps[t].items()}
    smp.update({f"floor_T{t:g}_{k}": v for t in floored for k, v in floored[t].items()})
    if args.json:
        refined = {f"refined_{k}": v for k, v in refined.items()}
        Path(args.json).write_text(json.dumps({**rec, **refined, **smp}, indent=2) + "\n")


if __name__ == "__main__":
    main()
