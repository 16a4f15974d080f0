"""One-frame pops: what ``mdvae denoise`` adds to clean studio takes, on their own skeletons.

A *pop* is a bone-frame whose world rotation, in the written file, leaves the midpoint of its
frames either side (slerp) by more than 5 degrees (and by more than 8) where the input's is
within 3: a jump for one frame that the input did not have. Each take goes through
``mdvae denoise`` as a whole process, this tree's and, with ``--baseline DIR``, another tree's
``mdvae_cli``; every take is read back with the project's own readers. Also per tree: the
mean over takes of each bone's mean world-rotation change (degrees) and of its 99.9th
percentile.

Takes (from ``../shared/data``, never copied into the project): CMU subject 01's ASF/AMC
takes, two AMC takes of each other CMU subject listed, HDM05 AMC takes (five per actor),
CMU BVH takes (every eighth, up to five) and the public BVH rigs of ``real/bvh``.

usage: python benchmarks/one_frame_pops.py [--baseline DIR] [--shared DIR] [--work DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.common import markdown_table  # noqa: E402
from mdvae_cli.formats.asf import load_asf  # noqa: E402
from mdvae_cli.geometry.kinematics import world_rotations  # noqa: E402
from mdvae_cli.infer.spike_worlds import world_jumps  # noqa: E402
from mdvae_cli.retarget.source_file import load_source  # noqa: E402

POP_DEG, BIG_POP_DEG, STILL_DEG = 5.0, 8.0, 3.0


def takes(shared: Path) -> list[tuple[str, Path, Path | None]]:
    """(group, take, its .asf or None) of every take measured."""
    out = []
    cmu = shared / "cmu" / "asfamc"
    for subject in sorted(p for p in cmu.iterdir() if p.is_dir()):
        amc = sorted(subject.glob("*.amc.gz"))
        picked = amc if subject.name == "01" else [amc[0], amc[len(amc) // 2]][: len(amc)]
        asf = subject / f"{subject.name}.asf"
        out += [(f"CMU {'01' if subject.name == '01' else 'others'} AMC", p, asf) for p in picked]
    hdm = shared / "hdm05"
    for actor in sorted(p for p in hdm.iterdir() if p.is_dir()):
        amc = sorted(actor.glob("*.amc.gz"))
        out += [("HDM05 AMC", p, actor / f"{actor.name}.asf") for p in amc[::12][:5]]
    out += [
        ("CMU BVH", p, None) for p in sorted((shared / "cmu" / "bvh").glob("*.bvh.gz"))[::8][:5]
    ]
    out += [
        ("public BVH rigs", p, None) for p in sorted((shared / "real" / "bvh").glob("*/*.bvh.gz"))
    ]
    return out


def worlds(path: Path, asf: Path | None) -> np.ndarray:
    """The take's world rotations (T, J, 3, 3)."""
    src = load_source(path, load_asf(asf) if asf else None)
    return world_rotations(np.asarray(src.rotations), src.parents)


def off_course(G: np.ndarray) -> np.ndarray:
    """Degrees each frame's rotation leaves its neighbours' slerp midpoint (0 at the ends).
    G: (T, J, 3, 3) -> (T, J)"""
    out = np.zeros(G.shape[:2])
    out[1:-1] = np.degrees(np.linalg.norm(world_jumps(G[:-2], G[1:-1], G[2:]), axis=-1))
    return out


def turned(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Degrees between rotations (..., 3, 3)."""
    cos = (np.trace(np.swapaxes(A, -1, -2) @ B, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def denoise(tree: Path, take: Path, asf: Path | None, out: Path) -> None:
    """``mdvae denoise`` of one take with the ``mdvae_cli`` of ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, "-c", "from mdvae_cli.cli.main import main; main()", "denoise",
           str(take), "-o", str(out)] + (["--asf", str(asf)] if asf else [])  # fmt: skip
    subprocess.run(cmd, env=env, cwd=tree, check=True, capture_output=True)  # not this tree


def measure(tree: Path, items, work: Path) -> dict[str, np.ndarray]:
    """Per group: rows of (pops, big pops, mean change, 99.9th percentile change)."""
    rows: dict[str, list] = {}
    for k, (group, take, asf) in enumerate(items):
        out = work / f"{k}_{take.name}"
        denoise(tree, take, asf, out)
        Gi, Go = worlds(take, asf), worlds(out, asf)
        di, do, change = off_course(Gi), off_course(Go), turned(Gi, Go)
        still = di < STILL_DEG
        rows.setdefault(group, []).append(
            [
                ((do > POP_DEG) & still).sum(),
                ((do > BIG_POP_DEG) & still).sum(),
                change.mean(),
                np.percentile(change, 99.9),
            ]  # fmt: skip
        )
        print(f"[{tree.name}] {take.name}: {rows[group][-1][:2]}", file=sys.stderr, flush=True)
    return {g: np.array(r, float) for g, r in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", help="a tree with another mdvae_cli to compare with")
    ap.add_argument("--shared", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--work", help="where the outputs go (default: a temporary folder)")
    args = ap.parse_args()
    items = takes(Path(args.shared))
    trees = [("before", Path(args.baseline))] if args.baseline else []
    trees.append(("now", REPO))
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        found = {}
        for name, tree in trees:
            (work / name).mkdir(parents=True, exist_ok=True)
            found[name] = measure(tree, items, work / name)
    groups = list(found["now"])
    body = []
    for g in [*groups, "all"]:
        cells = []
        for name, _ in trees:
            r = np.concatenate(list(found[name].values())) if g == "all" else found[name][g]
            cells.append(f"{r[:, 0].sum():.0f} / {r[:, 1].sum():.0f} / {r[:, 2].mean():.3f}"
                         f" / {r[:, 3].mean():.2f}")  # fmt: skip
        n = sum(len(v) for v in found["now"].values()) if g == "all" else len(found["now"][g])
        body.append([f"{g} ({n} takes)", *cells])
    head = ["takes"] + [
        f"{name}: pops > {POP_DEG:g}° / > {BIG_POP_DEG:g}° / mean change ° / 99.9th pct °"
        for name, _ in trees
    ]
    print(markdown_table(head, body))


if __name__ == "__main__":
    main()
