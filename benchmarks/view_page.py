"""Benchmark: the ``mdvae view`` page of a 10-minute take: its size and how fast it opens.

Builds a long clean take (real CMU takes one after another with ``--corpus``, else the
bundled example walk played forth and back), its noisy copy (Pose-NDF noise, sigma = 0.15,
seed 0) and the noisy copy cleaned by ``mdvae denoise`` (the default), then the pages
``noisy + clean`` (what ``mdvae view noisy.npz clean.npz`` writes) and ``noisy + clean + ground
truth``. Prints a markdown table: page size, build time, and in headless Chromium the time
from navigation to the first frame drawn (median of ``--repeats`` fresh browsers; the page's
own clock: ``performance.now()`` when its first frame is drawn) and to the data decoded.

    python benchmarks/view_page.py [--minutes 10] [--corpus data/corpus/cmu]
        [--out docs/benchmarks.md]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.view.page import build_view_page, write_view_page

try:
    from benchmarks import common
    from benchmarks.chromium import Chromium, file_url, find_chromium
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]
    from chromium import Chromium, file_url, find_chromium  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
SECTION_BEGIN = "<!-- view_page:begin (written by benchmarks/view_page.py) -->"
SECTION_END = "<!-- view_page:end -->"
FPS = 30.0


def concatenate(motions: Sequence[Motion], frames: int) -> Motion:
    """``frames`` frames of the motions one after another (at 30 Hz), each moved so that it
    starts where the one before ended (the first one's shape for all)."""
    parts, rot, body, extra, trans, end = [], [], [], [], [], None
    for m in motions:
        m = resample_motion(m, FPS)
        t = m.trans.copy()
        if end is not None:
            t[:, :2] += end - t[0, :2]
        end = t[-1, :2]
        rot.append(m.root_orient)
        body.append(m.pose_body)
        extra.append(m.pose_extra)
        trans.append(t)
        parts.append(m.num_frames)
        if sum(parts) >= frames:
            break
    first = motions[0]
    return first.with_body(
        root_orient=np.concatenate(rot)[:frames],
        pose_body=np.concatenate(body)[:frames],
        trans=np.concatenate(trans)[:frames],
        pose_extra=np.concatenate(extra)[:frames],
    )


def long_take(frames: int, corpus: Path | None) -> tuple[Motion, str]:
    """-> (the clean take, what it is made of)"""
    if corpus is not None:
        files = sorted(corpus.rglob("*.npz"))
        motions, total = [], 0
        for f in files:
            m = load_motion(f)
            motions.append(m)
            total += int(m.num_frames * FPS / m.fps)
            if total >= frames:
                break
        if total < frames:
            raise SystemExit(f"{corpus}: only {total} frames at 30 Hz, {frames} needed")
        return concatenate(motions, frames), f"{len(motions)} takes of `{corpus}` one after another"
    walk = load_motion(REPO / "examples/walk.npz")
    cycle = np.concatenate([np.arange(walk.num_frames), np.arange(walk.num_frames - 2, 0, -1)])
    idx = np.resize(cycle, frames)
    take = walk.with_body(
        walk.root_orient[idx], walk.pose_body[idx], walk.trans[idx], walk.pose_extra[idx]
    )
    return take, "examples/walk.npz played forth and back"


def open_times(path: Path, repeats: int) -> dict[str, float]:
    """Median milliseconds, over fresh headless browsers, from navigation to the page's data
    decoded and to its first frame drawn; and the wall time until the test hook says ready."""
    first, decoded, wall = [], [], []
    for _ in range(repeats):
        with Chromium.launch() as browser:
            tab = browser.open_page(width=1280, height=900)
            start = time.perf_counter()
            tab.navigate(file_url(path))
            tab.wait_for("window.mdvaeView && window.mdvaeView.ready", timeout=120, interval=0.01)
            wall.append(1000 * (time.perf_counter() - start))
            first.append(tab.evaluate("window.mdvaeView.firstFrameMs"))
            decoded.append(tab.evaluate("window.mdvaeView.decodedMs"))
            errors = tab.errors() + tab.evaluate("window.mdvaeView.errors")
            if errors:
                raise SystemExit(f"{path}: the page logged errors: {errors}")
    med = statistics.median
    return {"first_frame_ms": med(first), "decoded_ms": med(decoded), "ready_wall_ms": med(wall)}


def run(minutes: float, corpus: Path | None, repeats: int, folder: Path) -> tuple[list, str]:
    torch.set_num_threads(2)
    frames = int(round(minutes * 60 * FPS)) + 1
    gt, source = long_take(frames, corpus)
    noisy = add_pose_noise(gt, 0.15, np.random.default_rng(0))
    body = BodyModel(load_body_model(None))
    denoiser, _ = load_denoiser(None)
    clean = denoise_motions([noisy], denoiser, body, refine=RefineConfig(steps=0))[0]
    rows = []
    sets = {"noisy + clean": [("noisy", noisy), ("clean", clean)]}
    sets["noisy + clean + ground truth"] = sets["noisy + clean"] + [("ground truth", gt)]
    for label, items in sets.items():
        start = time.perf_counter()
        page = build_view_page(items, body)
        build_s = time.perf_counter() - start
        path = folder / f"{len(items)}.html"
        write_view_page(page, path)
        row = {"page": label, "frames": frames, "mb": page.num_bytes / 1e6, "build_s": build_s}
        if find_chromium() is not None:
            row.update(open_times(path, repeats))
        rows.append(row)
    return rows, source


def markdown(rows: list[dict], command: str, minutes: float, source: str, repeats: int) -> str:
    header = ["page", "motions x frames", "size (MB)", "build (s)", "first frame (ms)",
              "data decoded (ms)", "ready, wall (ms)"]  # fmt: skip
    body = []
    for r in rows:
        n = r["page"].count("+") + 1
        times = [f"{r[k]:.0f}" if k in r else "-" for k in
                 ("first_frame_ms", "decoded_ms", "ready_wall_ms")]  # fmt: skip
        body.append([r["page"], f"{n} x {r['frames']:,}", f"{r['mb']:.2f}", f"{r['build_s']:.1f}",
                     *times])  # fmt: skip
    machine = common.machine_description()
    return "\n".join([
        SECTION_BEGIN,
        f"## `mdvae view`: the page of a {minutes:g}-minute take",
        "",
        f"A {minutes:g}-minute 30 Hz take ({source}), its noisy copy (σ = 0.15 rad, seed 0) "
        "and that copy cleaned by `mdvae denoise`; built with the built-in body and its "
        "decimated mesh. Times are in headless Chromium (`--disable-gpu`, software drawing), "
        f"median of {repeats} fresh browsers, from navigation start: the data decoded, the "
        "first frame drawn (the page's own clock), and the wall time until the page says it "
        "is ready.",
        "",
        common.markdown_table(header, body),
        "",
        f"Machine: {machine['cpu']}, {machine['cores usable by this process']} cores usable "
        f"(shared with other work), {machine['date']}. Command: `{command}`.",
        SECTION_END,
        "",
    ])  # fmt: skip


def main(argv: Sequence[str] | None = None) -> str:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=10.0, help="length of the take")
    p.add_argument(
        "--corpus", type=Path, default=None,
        help="a folder of .npz takes to put one after another (default: the example walk)",
    )  # fmt: skip
    p.add_argument("--repeats", type=int, default=3, help="fresh browsers per page (median)")
    p.add_argument("--out", type=Path, default=None, help="write the section into this file")
    args = p.parse_args(argv)
    if find_chromium() is None:
        print("note: chromium not found: sizes only (apt-get install chromium for the times)")
    with tempfile.TemporaryDirectory() as tmp:
        rows, source = run(args.minutes, args.corpus, args.repeats, Path(tmp))
    command = f"python benchmarks/view_page.py --minutes {args.minutes:g} --repeats {args.repeats}"
    if args.corpus is not None:
        command += f" --corpus {args.corpus}"
    md = markdown(rows, command, args.minutes, source, args.repeats)
    print(md)
    if args.out is not None:
        common.write_section(args.out, md, SECTION_BEGIN, SECTION_END)
    return md


if __name__ == "__main__":
    main()
