"""Helpers shared by the benchmark scripts: clips, noise seeds, file-to-file timing, evaluation
with each ground truth posed only once, and a description of the machine.

Nothing here prints or writes outside the folders it is given.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.export import DEFAULT_CHUNK_FRAMES, pose_motion_chunks
from mdvae_cli.foot_metrics import compare_feet
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.metrics import (
    EvalResult,
    acceleration_error,
    joint_acceleration,
    mean_result,
    mpjpe,
    v2v,
)
from mdvae_cli.motion.contacts import foot_vertex_ids, lowest_sole_points
from mdvae_cli.motion.motion import Motion, slice_frames
from mdvae_cli.motion.noise import add_pose_noise, file_rng
from mdvae_cli.motion.resample import resample_motion

# --------------------------------------------------------------------------------------------
# clips


@dataclass
class Clip:
    """A fixed-length piece of a motion file.  name: ``<relative path>#<first frame>``."""

    name: str
    motion: Motion


def prior_and_windows(prior_path, corpus: Path, split: str, max_files: int):
    """A prior (default: the shipped one), its body model, and the 60-frame windows (every 60
    frames) of the first ``max_files`` files of a corpus split.
    -> (prior, its checkpoint metadata, body, files, WindowSet)"""
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.model.prior_model import load_prior
    from mdvae_cli.train.corpus import load_windows, select_files
    from mdvae_cli.weights import default_weights

    prior, meta = load_prior(prior_path or default_weights("prior"))
    body = BodyModel(load_body_model(meta["train_config"].get("body_model")))
    files = select_files([corpus], corpus / "split.json", split)[:max_files]
    return prior, meta, body, files, load_windows(files, body, 60, 60)


def cut_clips(motion: Motion, length: int, name: str) -> list[Clip]:
    """Non-overlapping clips of exactly ``length`` frames from the start; the remainder (fewer
    than ``length`` frames) is dropped."""
    if length < 3:
        raise ValueError(f"clips need at least 3 frames (for accelerations), got {length}")
    starts = range(0, motion.num_frames - length + 1, length)
    return [Clip(f"{name}#{s}", slice_frames(motion, s, s + length)) for s in starts]


def pick_evenly(items: Sequence, n: int | None) -> list:
    """At most ``n`` items spread evenly over the sequence (its order kept); None = all."""
    if n is None or n >= len(items):
        return list(items)
    if n <= 0:
        return []
    idx = np.unique(np.linspace(0, len(items) - 1, n).round().astype(int))
    return [items[i] for i in idx]


def load_clips(
    files: Sequence[Path],
    root: Path,
    length: int,
    fps: float = 30.0,
    max_clips: int | None = None,
    on_file: Callable[[Path], None] | None = None,
) -> list[Clip]:
    """Load files, resample to ``fps``, cut them into ``length``-frame clips and keep at most
    ``max_clips`` of them, spread evenly over all files (so every subject keeps a share)."""
    clips: list[Clip] = []
    for f in files:
        motion = resample_motion(load_motion(f), fps)
        clips += cut_clips(motion, length, Path(f).relative_to(root).as_posix())
        if on_file is not None:
            on_file(Path(f))
    return pick_evenly(clips, max_clips)


def join_files(
    files: Sequence[Path],
    minutes: float,
    fps: float,
    floor: Callable[[Motion, np.ndarray], float] | None = None,
) -> Motion:
    """One long take from ``files`` end to end (again from the first when they run out),
    ``minutes`` long at ``fps``: each one's root moved on to where the last one ended, and,
    with ``floor(motion, betas)`` (its floor height, z-up), lowered onto one floor; the first
    file's shape and gender."""
    need = int(round(minutes * 60 * fps))
    parts, n, end, first = [], 0, np.zeros(3), None
    while n < need:
        for f in files:
            m = resample_motion(load_motion(f), fps)
            first = m if first is None else first
            trans = np.array(m.trans, dtype=np.float64)
            trans[:, :2] += end[:2] - trans[0, :2]
            if floor is not None:
                trans[:, 2] -= floor(m, np.asarray(first.betas))
            end = trans[-1]
            parts.append((m.root_orient, m.pose_body, trans))
            n += m.num_frames
            if n >= need:
                break
    return Motion(
        root_orient=np.concatenate([p[0] for p in parts])[:need],
        pose_body=np.concatenate([p[1] for p in parts])[:need],
        trans=np.concatenate([p[2] for p in parts])[:need],
        betas=np.asarray(first.betas),
        fps=fps,
        gender=first.gender,
    )


def add_noise(clips: Sequence[Clip], sigma: float, seed: int) -> list[Motion]:
    """Pose-NDF noise on every clip, with a stream fixed by (seed, clip name, sigma): the same
    clip gets the same noise whatever the selection or order of the others."""
    return [
        add_pose_noise(c.motion, sigma, file_rng(seed, f"{c.name}@sigma={sigma:g}")) for c in clips
    ]


# --------------------------------------------------------------------------------------------
# timing


@dataclass
class Timing:
    """Wall-clock seconds spent on ``frames`` frames."""

    seconds: float
    frames: int

    @property
    def s_per_frame(self) -> float:
        return self.seconds / max(self.frames, 1)

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("inf")


def shipped_models_and_log(denoiser_path: str | Path | None = None):
    """The shipped denoiser (or the one at ``denoiser_path``), the built-in body and a logger
    that prints seconds since now, torch seeded: what each accuracy benchmark starts with.
    -> (denoiser, body, log)"""
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.model.denoiser import load_denoiser

    torch.manual_seed(0)
    body = BodyModel(load_body_model(None))
    denoiser, _ = load_denoiser(denoiser_path)
    start = time.time()

    def log(message: str) -> None:
        print(f"[{time.time() - start:6.0f} s] {message}", flush=True)

    return denoiser, body, log


def write_motions(motions: Sequence[Motion], folder: Path) -> list[Path]:
    """Save motions as ``clip_00000.npz``, ... in ``folder`` (created). -> the paths, in order"""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"clip_{i:05d}.npz" for i in range(len(motions))]
    for m, p in zip(motions, paths, strict=True):
        save_motion(m, p)
    return paths


def file_to_file(
    files: Sequence[Path],
    out_dir: Path,
    process: Callable[[list[Motion]], list[Motion]],
) -> tuple[list[Motion], Timing]:
    """Time one file-to-file run: load every file, ``process`` them all in one call, save every
    result into ``out_dir``. -> (the processed motions, the timing over all their frames)"""
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    motions = [load_motion(f) for f in files]
    outs = process(motions)
    for m, f in zip(outs, files, strict=True):
        save_motion(m, out_dir / Path(f).name)
    seconds = time.perf_counter() - start
    return outs, Timing(seconds, sum(m.num_frames for m in motions))


def warm_median_seconds(run: Callable[[], object], repeats: int) -> float:
    """Median wall-clock seconds of ``repeats`` calls after one untimed warm-up call."""
    run()
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def compact(pred: Motion, gt: Motion) -> Motion:
    """What evaluation needs of a prediction: its body parameters (float32, the body model's
    precision) on a copy of the ground truth clip, so hands and shape share its arrays."""
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return gt.with_body(f32(pred.root_orient), f32(pred.pose_body), f32(pred.trans))


# --------------------------------------------------------------------------------------------
# evaluation


@dataclass
class _Posed:
    joints: torch.Tensor  # (T, 22, 3) float64
    vertices: torch.Tensor  # (T, V, 3) float64
    soles: np.ndarray  # (T, 2) each foot's lowest vertex height


def _pose(motion: Motion, body: BodyModel, betas: np.ndarray) -> _Posed:
    chunks = list(
        pose_motion_chunks(motion, body, DEFAULT_CHUNK_FRAMES, vertices=True, betas=betas)
    )
    vertices = torch.cat([o.vertices for _, o in chunks]).double()
    return _Posed(
        torch.cat([o.joints for _, o in chunks]).double(),
        vertices,
        lowest_sole_points(vertices.numpy(), *foot_vertex_ids(body.data.weights)),
    )


def _compare(gt: _Posed, pred: _Posed, fps: float) -> EvalResult:
    """The numbers of :func:`mdvae_cli.metrics.evaluate_pair`, from already posed meshes."""
    T = gt.joints.shape[0]
    jg, jp = gt.joints, pred.joints
    accel = [None, None, None]
    if T >= 3:
        accel = [
            float(joint_acceleration(jg, fps).mean()),
            float(joint_acceleration(jp, fps).mean()),
            float(acceleration_error(jp, jg, fps).mean()),
        ]
    return EvalResult(
        num_frames=T,
        fps=float(fps),
        v2v_cm=100.0 * float(v2v(pred.vertices, gt.vertices, jp[:, 0], jg[:, 0]).sum()) / T,
        v2v_abs_cm=100.0 * float(v2v(pred.vertices, gt.vertices).sum()) / T,
        mpjpe_cm=100.0 * float(mpjpe(jp, jg).sum()) / T,
        accel_gt=accel[0],
        accel_pred=accel[1],
        accel_error=accel[2],
        **compare_feet(jg.numpy(), gt.soles, jp.numpy(), pred.soles, fps),
    )


def evaluate_clips(
    gt: Sequence[Motion],
    predictions: Mapping[Hashable, Sequence[Motion]],
    body: BodyModel,
) -> dict[Hashable, EvalResult]:
    """Frame-weighted mean metrics of every prediction set against the same ground truths.

    Same numbers as ``mean_result([evaluate_pair(g, p, body) ...])`` per set, but each ground
    truth clip is posed once for all sets. Every sequence in ``predictions`` lines up with ``gt``
    (and may compute its items lazily, see :class:`LazyMap`).
    """
    return {k: mean_result(v) for k, v in evaluate_per_clip(gt, predictions, body).items()}


def evaluate_per_clip(
    gt: Sequence[Motion],
    predictions: Mapping[Hashable, Sequence[Motion]],
    body: BodyModel,
) -> dict[Hashable, list[EvalResult]]:
    """As :func:`evaluate_clips`, but every clip's own metrics (not their mean)."""
    per_key: dict[Hashable, list[EvalResult]] = {k: [] for k in predictions}
    for i, g in enumerate(gt):
        posed_gt = _pose(g, body, g.betas)
        for key, preds in predictions.items():
            per_key[key].append(_compare(posed_gt, _pose(preds[i], body, g.betas), g.fps))
    return per_key


class LazyMap(Sequence):
    """``fn(items[i])`` computed when item i is read, never stored."""

    def __init__(self, fn: Callable, items: Sequence):
        self.fn, self.items = fn, items

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i):
        return self.fn(self.items[i])

    def __iter__(self) -> Iterator:
        return (self.fn(x) for x in self.items)


# --------------------------------------------------------------------------------------------
# markdown


def markdown_table(header: Sequence[str], body: Sequence[Sequence[str]]) -> str:
    """A GitHub markdown table from header cells and rows of cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    return "\n".join(lines)


def write_section(path: Path, section: str, begin: str, end: str) -> None:
    """Put ``section`` (which starts with the ``begin`` marker line and ends with ``end``) into
    the markdown file ``path``: it replaces the marked section if there is one, else it is
    appended; the rest of the file is kept. A new file gets a title."""
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    i, j = text.find(begin), text.find(end)
    if i >= 0 and j > i:
        text = text[:i] + section.rstrip("\n") + text[j + len(end) :]
    else:
        text = text.rstrip("\n") + "\n\n" + section
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text if text.endswith("\n") else text + "\n")
    try:
        from benchmarks import help_figures
    except ModuleNotFoundError:  # run as a file
        import help_figures  # type: ignore[no-redef]
    if path.resolve() == help_figures.DOCS.resolve():  # the help texts quote these tables
        help_figures.write()


# --------------------------------------------------------------------------------------------
# machine


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine_description() -> dict[str, str]:
    """What the timings depend on: CPU, cores, library versions, threads, date."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 0
    return {
        "cpu": cpu_model(),
        "logical cores": str(os.cpu_count()),
        "cores usable by this process": str(usable),
        "torch threads": str(torch.get_num_threads()),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "os": f"{platform.system()} {platform.release()}",
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }
