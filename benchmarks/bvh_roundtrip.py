"""BVH in, BVH out: how much the way back changes a take, and how noisy takes come back.

Clean round trip (real BVH files from ten rigs): each take is retargeted onto the body at its
own rate and written back on its own skeleton, once unchanged ("identity": the way back alone)
and once through the default denoiser. Reported per file: median change of every joint's local
rotation (degrees; joints with rotation channels, fingers included) and mean change of every
joint's world position (mm, end sites included).

Noisy takes: Gaussian noise (--sigma rad on each Euler channel of every joint) is added to clean
takes; then (a) the npz path: the noisy take imported as SMPL, denoised; (b) the BVH path:
``mdvae denoise noisy.bvh -o out.bvh``, the output imported again. Both are scored as the mean
distance of the 22 body joints from the clean take's import (mm); the BVH path also on the
take's own skeleton (every joint, mm).

usage: python benchmarks/bvh_roundtrip.py [--frames N] [--sigma RAD] [--quick] [--clean-only]
"""

from __future__ import annotations

import argparse
import glob
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.bvh_write import write_bvh
from mdvae_cli.geometry.euler import euler_to_rotmat, rotmat_to_euler
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.take import read_take
from mdvae_cli.retarget.way_back import file_pose, smpl_globals, write_back_data

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"


def real_files() -> list[Path]:
    files = sorted(glob.glob(str(DATA / "real" / "bvh" / "*" / "*.bvh.gz")))
    files += sorted(glob.glob(str(DATA / "animated_drawings" / "*.bvh.gz")))
    return [Path(f) for f in files]


def cmu_files(n: int) -> list[Path]:
    return [Path(f) for f in sorted(glob.glob(str(DATA / "cmu" / "bvh" / "*.bvh.gz")))[:n]]


def changes(take, data: np.ndarray) -> tuple[float, float]:
    """(median local-rotation change in degrees, mean world-position change in mm) between the
    take's own frames and ``data`` (F, C) written for it."""
    layout = take.source.layout
    L0, _, _, P0 = file_pose(take.source, layout, layout.data[layout.rows])
    L1, _, _, P1 = file_pose(take.source, layout, data[layout.rows])
    rot = [j for j in range(take.source.num_joints) if layout.joint_columns(j, "r")]
    R = np.swapaxes(L0[:, rot], -1, -2) @ L1[:, rot]
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    mm = np.linalg.norm(P1 - P0, axis=-1).mean() * layout.metres_per_unit * 1000
    return float(np.degrees(np.median(np.arccos(cos)))), float(mm)


def add_noise(take, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """The take's frames with every rotation channel perturbed by N(0, sigma) rad.  -> (F, C)"""
    layout = take.source.layout
    data = layout.data.copy()
    for j in range(take.source.num_joints):
        cols = layout.joint_columns(j, "r")
        if len(cols) != 3:
            continue
        axes = "".join(a for _, a in cols)
        idx = [c for c, _ in cols]
        ang = np.deg2rad(data[:, idx])
        R = euler_to_rotmat(ang, axes)
        noise = rng.normal(0.0, sigma, ang.shape)
        R = R @ euler_to_rotmat(noise, "xyz")
        data[:, idx] = np.rad2deg(rotmat_to_euler(R, axes, near=ang))
    return data


def body_joints_mm(a, b, body: BodyJoints) -> float:
    """Mean distance (mm) of the 22 body joints of two motions of the same frames."""
    return float(np.linalg.norm(smpl_globals(a, body)[1] - smpl_globals(b, body)[1], axis=-1)
                 .mean() * 1000)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=900, help="frames read per take")
    ap.add_argument("--sigma", type=float, default=0.05, help="noise per Euler channel, rad")
    ap.add_argument("--cmu", type=int, default=4, help="CMU BVH takes in the noisy table")
    ap.add_argument("--quick", action="store_true", help="3 real files, 2 CMU, 300 frames")
    ap.add_argument("--clean-only", action="store_true", help="only the clean-take table")
    args = ap.parse_args()
    torch.set_num_threads(1)
    reals = real_files()
    if not reals:
        raise SystemExit(f"no BVH files under {DATA}")
    if args.quick:
        reals, args.cmu, args.frames = reals[:3], 2, 300
    data = load_body_model(None)
    joints, body = BodyJoints(data), BodyModel(data)
    denoiser, _ = load_denoiser(None)
    refine = RefineConfig(steps=0)

    def clean(motion):
        return denoise_motions([motion], denoiser, body, 60, 45, refine=refine)[0]

    def read(path):
        from mdvae_cli.retarget.retarget import load_source

        src = load_source(path, max_frames=args.frames)
        return read_take(path, joints, source=src)

    print(f"## Clean takes: change made by the way back ({args.frames} frames at most per take)")
    print("| file | rig | frames | fps | identity: rot deg / pos mm | denoised: rot deg / pos mm "
          "| denoiser's own change (SMPL joints, mm) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    summary = []
    for path in reals:
        t0 = time.perf_counter()
        take = read(path)
        same = write_back_data(take.source, take.retarget, take.motion, take.motion, joints)
        cleaned = clean(take.motion)
        out = write_back_data(take.source, take.retarget, take.motion, cleaned, joints)
        r0, p0 = changes(take, same)
        r1, p1 = changes(take, out)
        summary.append((r1, p1))
        print(f"| {path.name.removesuffix('.bvh.gz')} | {path.parent.name} | "
              f"{take.source.num_frames} | {take.source.fps:g} | {r0:.2g} / {p0:.2g} | "
              f"{r1:.2f} / {p1:.1f} | {body_joints_mm(cleaned, take.motion, joints):.1f} |"
              f"  <!-- {time.perf_counter() - t0:.1f} s -->")  # fmt: skip
    med = np.median([r for r, _ in summary])
    print(f"\nall files: median of the per-file rotation medians {med:.2f} deg, mean position "
          f"change {np.mean([p for _, p in summary]):.1f} mm\n")  # fmt: skip
    if args.clean_only:
        return

    print(f"## Noisy takes (sigma {args.sigma} rad per Euler channel)")
    print("| file | noisy | npz path | BVH path (re-imported) | BVH path, own skeleton: "
          "noisy -> cleaned |")  # fmt: skip
    print("|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in cmu_files(args.cmu) + reals[: 3 if args.quick else len(reals)]:
            take = read(path)
            noisy_data = add_noise(take, args.sigma, rng)
            noisy_file = Path(tmp) / "noisy.bvh"
            write_bvh(take.source.layout, noisy_data, noisy_file)
            from mdvae_cli.retarget.retarget import load_source

            nsrc = load_source(noisy_file, max_frames=args.frames, scale=take.source.info[
                "metres_per_unit"])  # fmt: skip
            noisy = read_take(noisy_file, joints, betas=take.retarget.betas, source=nsrc)
            cleaned = clean(noisy.motion)
            npz = body_joints_mm(cleaned, take.motion, joints)
            back = write_back_data(noisy.source, noisy.retarget, noisy.motion, cleaned, joints)
            out_file = Path(tmp) / "out.bvh"
            write_bvh(noisy.source.layout, back, out_file)
            osrc = load_source(out_file, max_frames=args.frames, scale=take.source.info[
                "metres_per_unit"])  # fmt: skip
            again = read_take(out_file, joints, betas=take.retarget.betas, source=osrc)
            bvh = body_joints_mm(again.motion, take.motion, joints)
            before = body_joints_mm(noisy.motion, take.motion, joints)
            own_noisy = changes(take, noisy_data)[1]
            own_clean = changes(take, back)[1]
            rows.append((before, npz, bvh))
            print(f"| {path.name.removesuffix('.bvh.gz')} | {before:.1f} | {npz:.1f} | {bvh:.1f} "
                  f"| {own_noisy:.1f} -> {own_clean:.1f} |")  # fmt: skip
    m = np.mean(rows, axis=0)
    print(f"\nmean joint error (mm): noisy {m[0]:.1f}, npz path {m[1]:.1f}, BVH path {m[2]:.1f}")


if __name__ == "__main__":
    main()
