"""ASF/AMC in, AMC out: how much the way back changes a take, and how noisy takes come back.

Clean round trip (CMU and HDM05 takes): each take is retargeted onto the body at its own rate
and written back on its own skeleton, once unchanged ("identity": the way back alone) and once
through the default denoiser. Reported per file: the largest change of any dof value (degrees)
and whether the written file is byte-identical to the input (identity); the median change of
every bone's local rotation (degrees; bones with rotation dofs, fingers included) and the mean
change of every joint's world position (mm, bone tips included) after denoising.

Noisy takes: Gaussian noise (--sigma rad) is added to every rotation dof value of every bone
(root included) of clean CMU takes; then (a) the npz path: the noisy take imported as SMPL,
denoised; (b) the AMC path: ``mdvae denoise noisy.amc -o out.amc``, the output imported again
(in the clean import's frame: its floor and levelling, not a floor fitted anew). Both are
scored as the mean distance of the 22 body joints from the clean take's import (mm); the AMC
path also on the take's own skeleton (every joint, mm).

usage: python benchmarks/amc_roundtrip.py [--frames N] [--sigma RAD] [--takes N] [--hdm05 N]
       [--quick]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.amc_write import amc_text, write_amc
from mdvae_cli.formats.asf import load_asf
from mdvae_cli.formats.source import read_text
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion import cmu
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.retarget import RetargetSettings, import_motion, load_source
from mdvae_cli.retarget.take import read_take
from mdvae_cli.retarget.way_back import smpl_globals
from mdvae_cli.retarget.way_back_amc import amc_pose, write_back_amc

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"


def cmu_takes(n: int) -> list[tuple[Path, Path, float]]:
    """(amc, asf, capture fps): the first trial of each of the first n CMU subjects."""
    out = []
    for folder in sorted((DATA / "cmu" / "asfamc").glob("*"), key=lambda p: int(p.name)):
        amcs = sorted(folder.glob("*.amc.gz"))
        asf = folder / f"{folder.name}.asf"
        if amcs and asf.is_file():
            out.append((amcs[0], asf, cmu.capture_fps(folder.name)))
    return out[:n]


def hdm05_takes(n: int) -> list[tuple[Path, Path, float]]:
    """(amc, asf, 120): the first clip of each HDM05 actor (another lab's skeletons)."""
    out = []
    for folder in sorted((DATA / "hdm05").glob("*")):
        amcs = sorted(folder.glob("*.amc.gz"))
        if amcs and (folder / f"{folder.name}.asf").is_file():
            out.append((amcs[0], folder / f"{folder.name}.asf", 120.0))
    return out[:n]


def _pose(take, values: dict[str, np.ndarray]):
    """Local rotations and world positions (metres) of the take's frames in ``values``."""
    layout = take.source.layout
    rows = {b: v[layout.rows] for b, v in values.items()}
    L, _, _, P = amc_pose(take.source, layout, rows)
    return L, P * layout.metres_per_unit


def changes(take, values: dict[str, np.ndarray]) -> tuple[float, float]:
    """(median local-rotation change in degrees over bones with rotation dofs, mean
    world-position change in mm) between the take's own values and ``values``."""
    L0, P0 = _pose(take, take.source.layout.values)
    L1, P1 = _pose(take, values)
    src, layout = take.source, take.source.layout
    rot = [j for j, name in enumerate(src.names) if name in layout.values
           and any(d.startswith("r") for d in layout.dofs(name))]  # fmt: skip
    R = np.swapaxes(L0[:, rot], -1, -2) @ L1[:, rot]
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    mm = np.linalg.norm(P1 - P0, axis=-1).mean() * 1000
    return float(np.degrees(np.median(np.arccos(cos)))), float(mm)


def largest_change_deg(take, values: dict[str, np.ndarray]) -> float:
    """Largest change of any rotation dof value, degrees."""
    layout = take.source.layout
    to_deg = 1.0 if layout.degrees else 180.0 / math.pi
    worst = 0.0
    for bone, old in layout.values.items():
        cols = [i for i, d in enumerate(layout.dofs(bone)) if d.startswith("r")]
        if cols:
            worst = max(worst, float(np.abs(values[bone][:, cols] - old[:, cols]).max()))
    return worst * to_deg


def add_noise(take, sigma: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The take's values with N(0, sigma rad) added to every rotation dof value."""
    layout = take.source.layout
    unit = 180.0 / math.pi if layout.degrees else 1.0
    out = {}
    for bone, v in layout.values.items():
        v = v.copy()
        cols = [i for i, d in enumerate(layout.dofs(bone)) if d.startswith("r")]
        v[:, cols] += rng.normal(0.0, sigma, (v.shape[0], len(cols))) * unit
        out[bone] = v
    return out


def file_match(written: str, original: str) -> str:
    """One of: same bytes; same lines (only line endings differ); differs."""
    if written == original:
        return "same bytes"
    return "same lines" if written.splitlines() == original.splitlines() else "differs"


def joints_in_frame_of(take, src, body: BodyJoints) -> np.ndarray:
    """The 22 body joints (T, 22, 3) of ``src`` (the take written back) imported with the
    take's body shape and placed in the take's own output frame (its floor and levelling):
    a re-import fits its own floor, and a floor tilted by 1 degree over a walk of a few
    metres would move every joint by centimetres that have nothing to do with the pose."""
    rt = import_motion(src, body, fps=None, betas=take.retarget.betas,
                       settings=RetargetSettings(floor="none"))  # fmt: skip
    turn = np.asarray(take.retarget.to_output) @ np.asarray(rt.to_output).T
    P = smpl_globals(rt.motion, body)[1] + rt.drop
    return P @ turn.T - take.retarget.drop


def body_joints_mm(a, b, body: BodyJoints) -> float:
    """Mean distance (mm) of the 22 body joints of two motions of the same frames."""
    return float(np.linalg.norm(smpl_globals(a, body)[1] - smpl_globals(b, body)[1], axis=-1)
                 .mean() * 1000)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=600, help="frames read per take")
    ap.add_argument("--sigma", type=float, default=0.05, help="noise per dof value, rad")
    ap.add_argument("--takes", type=int, default=8, help="CMU takes (first trial per subject)")
    ap.add_argument("--hdm05", type=int, default=4, help="HDM05 takes in the clean table")
    ap.add_argument("--quick", action="store_true", help="2 CMU takes, 1 HDM05, 240 frames")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.quick:
        args.takes, args.hdm05, args.frames = 2, 1, 240
    takes = cmu_takes(args.takes)
    if not takes:
        raise SystemExit(f"no CMU ASF/AMC takes under {DATA}")
    data = load_body_model(None)
    joints, body = BodyJoints(data), BodyModel(data)
    denoiser, _ = load_denoiser(None)
    refine = RefineConfig(steps=0)

    def clean(motion):
        return denoise_motions([motion], denoiser, body, 60, 45, refine=refine)[0]

    def read(path, asf, fps, betas=None):
        src = load_source(path, load_asf(asf), fps=fps, max_frames=args.frames)
        return read_take(path, joints, source=src, betas=betas)

    print(f"## Clean takes: change made by the way back ({args.frames} frames at most per take)")
    print("| file | frames | fps | identity: largest dof change deg / file | denoised: rot deg / "
          "pos mm | denoiser's own change (SMPL joints, mm) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for path, asf, fps in takes + hdm05_takes(args.hdm05):
        t0 = time.perf_counter()
        take = read(path, asf, fps)
        layout = take.source.layout
        same = write_back_amc(take.source, take.retarget, take.motion, take.motion, joints)
        exact = file_match(amc_text(layout, same), read_text(path, "surrogateescape"))
        cleaned = clean(take.motion)
        out = write_back_amc(take.source, take.retarget, take.motion, cleaned, joints)
        r1, p1 = changes(take, out)
        print(f"| {path.name.removesuffix('.amc.gz')} | {take.source.num_frames} | {fps:g} | "
              f"{largest_change_deg(take, same):.1g} / {exact} | {r1:.2f} / {p1:.1f} | "
              f"{body_joints_mm(cleaned, take.motion, joints):.1f} |"
              f"  <!-- {time.perf_counter() - t0:.1f} s -->")  # fmt: skip

    print(f"\n## Noisy takes (sigma {args.sigma} rad per dof value)")
    print("| file | noisy | npz path | AMC path (re-imported) | AMC path, own skeleton: "
          "noisy -> cleaned |")  # fmt: skip
    print("|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path, asf, fps in takes:
            take = read(path, asf, fps)
            betas = take.retarget.betas
            noisy_values = add_noise(take, args.sigma, rng)
            noisy_file = Path(tmp) / "noisy.amc"
            write_amc(take.source.layout, noisy_values, noisy_file)
            noisy = read(noisy_file, asf, fps, betas)
            cleaned = clean(noisy.motion)
            npz = body_joints_mm(cleaned, take.motion, joints)
            back = write_back_amc(noisy.source, noisy.retarget, noisy.motion, cleaned, joints)
            out_file = Path(tmp) / "out.amc"
            write_amc(noisy.source.layout, back, out_file)
            again = joints_in_frame_of(take, load_source(out_file, load_asf(asf), fps=fps,
                                       max_frames=args.frames), joints)  # fmt: skip
            amc = float(np.linalg.norm(again - smpl_globals(take.motion, joints)[1], axis=-1)
                        .mean() * 1000)  # fmt: skip
            before = body_joints_mm(noisy.motion, take.motion, joints)
            P = _pose(take, take.source.layout.values)[1]
            own = [np.linalg.norm(_pose(take, v)[1] - P, axis=-1).mean() * 1000
                   for v in (noisy_values, back)]  # fmt: skip
            rows.append((before, npz, amc))
            print(f"| {path.name.removesuffix('.amc.gz')} | {before:.1f} | {npz:.1f} | {amc:.1f} "
                  f"| {own[0]:.1f} -> {own[1]:.1f} |")  # fmt: skip
    m = np.mean(rows, axis=0)
    print(f"\nmean joint error (mm): noisy {m[0]:.1f}, npz path {m[1]:.1f}, AMC path {m[2]:.1f}")


if __name__ == "__main__":
    main()
