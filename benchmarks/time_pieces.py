"""Long takes in pieces of time: a take denoised a piece at a time (``infer.time_pieces``,
what ``mdvae denoise`` does to a take over 1.5 x 32,768 frames) against the same take
denoised whole, on the corpus's ``test`` and ``unseen_test`` splits.

A take of ``--minutes`` at ``--fps`` is made from a split's files end to end (each one's root
moved on to where the last one ended and its floor, the 5th percentile of its lowest foot
joint, put at zero: one continuous take on one floor), clean and with Pose-NDF noise
(sigma 0.10 rad). Rows: the take denoised whole (one piece), in the default's pieces, and in
pieces of ``--short-piece`` seconds (many more cuts: what the hand-overs cost, magnified).
Columns: MPJPE (cm, root-relative) and the mean joint angle error (degrees) against the clean
take; MPJPE within 10 s of a cut of the short pieces; and how far the rotations are from the
whole take's (median and 99th percentile, rad). Joints only: posing every vertex of a
10-minute 120 Hz take takes minutes.

    python benchmarks/time_pieces.py [--minutes 10] [--fps 120] [--short-piece 60] [--write]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]

from mdvae_cli.export import pose_motion_chunks
from mdvae_cli.geometry.rotations import rotvec_to_quat
from mdvae_cli.infer import time_pieces
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.metrics import mpjpe
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.train.corpus import select_files

REPO = Path(__file__).resolve().parents[1]
SIGMAS = (0.0, 0.10)
#: frames this close to a cut (seconds) make the "near a cut" column
NEAR_SECONDS = 10.0
BEGIN = "<!-- time_pieces:begin (written by benchmarks/time_pieces.py) -->"
END = "<!-- time_pieces:end -->"


def floor_height(motion: Motion, body, betas: np.ndarray) -> float:
    """The 5th percentile of the lowest foot joint's height (z-up), metres."""
    chunks = pose_motion_chunks(motion, body, 4096, vertices=False, betas=betas)
    low = [out.joints.double().numpy()[:, [7, 8, 10, 11], 2].min(axis=1) for _, out in chunks]
    return float(np.percentile(np.concatenate(low), 5))


def long_take(files: list[Path], minutes: float, fps: float, body) -> Motion:
    """The split's files end to end on one floor (module docstring), ``minutes`` at ``fps``."""
    return common.join_files(files, minutes, fps, lambda m, betas: floor_height(m, body, betas))


def frame_errors(clean: Motion, pred: Motion, body) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, MPJPE (cm, root-relative) and the mean angle between each joint's rotation
    and the clean one's (degrees), against the clean take (joints only: posing every vertex
    of a 10-minute 120 Hz take takes minutes).  -> (T,), (T,)"""
    out_j = []
    chunks = zip(pose_motion_chunks(clean, body, 4096, vertices=False, betas=clean.betas),
                 pose_motion_chunks(pred, body, 4096, vertices=False, betas=clean.betas),
                 strict=True)  # fmt: skip
    for (_, g), (_, p) in chunks:
        jg, jp = g.joints.double(), p.joints.double()
        out_j.append(100 * mpjpe(jp - jp[:, :1], jg - jg[:, :1]).numpy())
    qa = rotvec_to_quat(torch.as_tensor(clean.joint_rotations, dtype=torch.float64))
    qb = rotvec_to_quat(torch.as_tensor(pred.joint_rotations, dtype=torch.float64))
    angle = 2 * torch.arccos((qa * qb).sum(-1).abs().clamp(max=1.0))
    return np.concatenate(out_j), np.degrees(angle.numpy()).mean(axis=1)


def split_rows(split: str, args, denoiser, body) -> list[list[str]]:
    corpus = REPO / "data" / "corpus"
    files = select_files([corpus], corpus / "split.json", split)
    clean = long_take(files, args.minutes, args.fps, body)
    short = int(round(args.short_piece * args.fps))
    runs = {"whole (one piece)": 10 * clean.num_frames, "the default's pieces": None,
            f"pieces of {args.short_piece:g} s": short}  # fmt: skip
    plan = time_pieces.plan_pieces(np.ones(clean.num_frames, bool), clean.fps, short)
    near = np.zeros(clean.num_frames, bool)
    for c in plan.cuts[1:-1]:
        near[max(0, c - int(NEAR_SECONDS * args.fps)) : c + int(NEAR_SECONDS * args.fps)] = True
    rows = []
    for sigma in SIGMAS:
        noisy = add_pose_noise(clean, sigma, np.random.default_rng(0)) if sigma else clean
        whole = None
        for name, piece in runs.items():
            saved = time_pieces.PIECE_FRAMES
            time_pieces.PIECE_FRAMES = saved if piece is None else piece
            try:
                out = denoise([noisy], DenoiseSettings(), denoiser, body)[0]
            finally:
                time_pieces.PIECE_FRAMES = saved
            whole = out if whole is None else whole
            e_j, e_a = frame_errors(clean, out, body)
            gap = np.linalg.norm(out.joint_rotations - whole.joint_rotations, axis=-1)
            size = time_pieces.PIECE_FRAMES if piece is None else piece
            cuts = time_pieces.plan_pieces(np.ones(clean.num_frames, bool), clean.fps, size)
            count = 1 if cuts is None else len(cuts.spans)
            rows.append([split, f"{sigma:.2f}", name, str(count), f"{e_j.mean():.3f}",
                         f"{e_a.mean():.3f}", f"{e_j[near].mean():.3f}",
                         f"{np.median(gap):.1e}", f"{np.percentile(gap, 99):.1e}"])  # fmt: skip
            print(" | ".join(rows[-1]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=120.0)
    ap.add_argument("--short-piece", type=float, default=60.0, help="seconds a short piece")
    ap.add_argument("--splits", default="test,unseen_test")
    ap.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    args = ap.parse_args(argv)
    denoiser, body, _ = common.shipped_models_and_log()
    rows = [r for s in args.splits.split(",") for r in split_rows(s, args, denoiser, body)]
    header = ["split", "sigma", "run", "pieces", "MPJPE cm", "joint angle error (deg)",
              f"MPJPE within {NEAR_SECONDS:g} s of a short piece's cut", "rad from whole, median",
              "rad from whole, p99"]  # fmt: skip
    section = (
        f"{BEGIN}\n## Long takes in pieces of time (`benchmarks/time_pieces.py`)\n\n"
        f"A {args.minutes:g}-minute take at {args.fps:g} Hz per split (module docstring), "
        "denoised whole and in pieces with the default settings.\n\n"
        + common.markdown_table(header, rows)
        + f"\n\n({common.cpu_model()}; `python benchmarks/time_pieces.py --minutes "
        f"{args.minutes:g} --fps {args.fps:g} --short-piece {args.short_piece:g}`)\n{END}"
    )
    print(section)
    if args.write:
        common.write_section(REPO / "docs" / "benchmarks.md", section, BEGIN, END)


if __name__ == "__main__":
    main()
