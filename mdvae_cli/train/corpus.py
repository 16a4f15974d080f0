"""Training data: motion files (and split files) -> canonical state windows (x0, x_1..x_T) at
the model rate."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import expand_inputs
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.model.chunks import MODEL_FPS, chunk_states, motion_to_params
from mdvae_cli.model.state import BodyParams
from mdvae_cli.motion.mirror import mirror_motion
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import resample_motion, resample_times, time_warp


@dataclass
class WindowSet:
    """N windows of canonical states.  x0: (N, D), x: (N, T, D), betas: (N, S)."""

    x0: torch.Tensor
    x: torch.Tensor
    betas: torch.Tensor

    def __len__(self) -> int:
        return int(self.x0.shape[0])

    def subset(self, idx: torch.Tensor) -> WindowSet:
        return WindowSet(self.x0[idx], self.x[idx], self.betas[idx])

    @staticmethod
    def concat(sets: list[WindowSet]) -> WindowSet:
        return WindowSet(*(torch.cat([getattr(s, k) for s in sets]) for k in ("x0", "x", "betas")))


def motion_windows(motion: Motion, body: BodyModel, length: int, stride: int) -> WindowSet | None:
    """Cut a motion already at the model rate into windows of ``length`` + 1 frames."""
    T = motion.num_frames
    if T < length + 1:
        return None
    p = motion_to_params(motion)
    starts = torch.arange(0, T - length, stride)
    idx = starts[:, None] + torch.arange(length + 1)[None]
    chunks = BodyParams(p.root_orient[idx], p.pose_body[idx], p.trans[idx])
    betas = torch.as_tensor(motion.betas, dtype=torch.float32).expand(len(starts), -1)
    betas = body.fit_betas(betas)
    with torch.no_grad():
        states, _ = chunk_states(chunks, betas, body)
    return WindowSet(states[:, 0].contiguous(), states[:, 1:].contiguous(), betas.contiguous())


def read_split(split_file: Path) -> dict[str, list[Path]]:
    """A split file: JSON ``{"train": [...], "val": [...], "test": [...]}`` of paths relative
    to the file's folder."""
    split_file = Path(split_file)
    try:
        raw = json.loads(split_file.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"split file {split_file} is unreadable ({exc})") from None
    splits = raw.get("splits", raw) if isinstance(raw, dict) else None
    if not isinstance(splits, dict):
        raise InputError(
            f'split file {split_file} must be a JSON object {{"train": [...], "val": [...]}}'
        )
    out = {}
    for name, files in splits.items():
        if name in ("train", "val", "test") and not (
            isinstance(files, list) and all(isinstance(p, str) for p in files)
        ):
            raise InputError(f'split file {split_file}: "{name}" must be a list of file paths')
        if isinstance(files, list):
            out[name] = [split_file.parent / p for p in files if isinstance(p, str)]
    return out


def select_files(
    data: list[Path], split_file: Path | None, split: str, val_fraction: float = 0.1
) -> list[Path]:
    """The motion files of one split.

    With a split file, its list for ``split`` intersected with what ``data`` contains; without
    one, a deterministic hold-out of every ``1/val_fraction``-th file for ``val``.
    """
    files = [f for f, _ in expand_inputs(data, by_target=True)]
    if split_file is not None:
        wanted = {p.resolve() for p in read_split(split_file).get(split, [])}
        return [f for f in files if f.resolve() in wanted]
    every = max(2, round(1 / val_fraction))
    if split == "val":
        return files[::every]
    return [f for i, f in enumerate(files) if i % every != 0]


def no_training_files(data: list[Path], split: Path | None, val_files: list[Path]) -> str:
    """Why a run found nothing to train on, and what to do about it."""
    if split is not None:
        found = len(expand_inputs(data, by_target=True))
        return (
            f'none of the {found} motion files found is in the "train" list of {split} '
            "(its paths are relative to its folder)"
        )
    if not val_files:
        takes = expand_inputs(data, (".bvh", ".amc"))
        if takes:  # a studio's takes: the importer makes the npz files training reads
            return (
                f"no .npz motion files found in the given data paths, only {len(takes)} "
                f"BVH/AMC take{'s' if len(takes) > 1 else ''}: convert them first with "
                f"`mdvae import {' '.join(str(p) for p in data)} -o imported/` and train on "
                "imported/"
            )
        return "no motion files found in the given data paths"
    n = len(val_files)
    return (
        f"found {n} motion file{'s' if n > 1 else ''} and the automatic split put "
        f"{'them all' if n > 1 else 'it'} into validation, leaving none to train on: give 2 or "
        'more files, or a --split file ({"train": [...], "val": [...]}) that lists the '
        "training files"
    )


def check_val_splits(names: list[str], split: Path) -> None:
    """InputError for a --val-split the split file has no list of (a typo would leave the
    run without validation); a file without the default, "val", trains without one."""
    lists = read_split(split)
    for name in names:
        if name not in lists and name != "val":
            raise InputError(
                f'--val-split {name}: the split file {split} has no "{name}" list (it has '
                f"{', '.join(lists) or 'none'})"
            )


def no_validation(val_files: int, window: int) -> str:
    """The note of a run without validation windows: why, and what chooses its best
    checkpoint instead."""
    why = (
        "no validation files found"
        if not val_files
        else f"the {val_files} validation file{'s are' if val_files > 1 else ' is'} shorter than "
        f"a window ({window + 1} frames at 30 Hz)"
    )
    return f"{why}: the best checkpoint is chosen by the training loss"


def outside(files: list[Path], folder: Path) -> list[Path]:
    """``files`` less those inside ``folder`` (e.g. a run folder kept among the data)."""
    root = Path(folder).resolve()
    return [f for f in files if not Path(f).resolve().is_relative_to(root)]


def fraction_of(motions: list[Motion], fraction: float, seed: int) -> list[int]:
    """Indices of a seeded random subset of whole motions holding about ``fraction`` of all
    their frames (the data-scaling runs: the same recipe on 25 / 50 % of the minutes). The
    subsets are nested: a smaller fraction with the same seed keeps a prefix of a larger
    one's order."""
    if fraction >= 1.0:
        return list(range(len(motions)))
    order = np.random.default_rng(seed).permutation(len(motions))
    total = sum(m.num_frames for m in motions)
    keep, frames = [], 0
    for i in order:
        if frames >= fraction * total:
            break
        keep.append(int(i))
        frames += motions[i].num_frames
    return sorted(keep)


def load_training_motion(path: Path) -> Motion:
    """``load_motion``, with a plain error for a checkpoint of an mdvae run (a run folder
    kept inside a data folder) instead of the list of its weights' names."""
    try:
        return load_motion(path)
    except InputError:
        meta = Path(path).with_suffix(".json")
        try:
            kind = json.loads(meta.read_text()) if meta.is_file() else None
        except (OSError, UnicodeDecodeError, ValueError):
            kind = None
        if isinstance(kind, dict) and ("model_config" in kind or "kind" in kind):
            raise InputError(
                f"{path}: a checkpoint of an mdvae run, not motion: keep run folders out of "
                "the data folders"
            ) from None
        raise


def load_windows(
    files: list[Path],
    body: BodyModel,
    length: int,
    stride: int,
    on_file: Callable[[Path], None] | None = None,
    mirror: bool = False,
    speeds: tuple[float, ...] = (1.0,),
    fraction: float = 1.0,
    fraction_seed: int = 0,
    required: bool = True,
) -> WindowSet | None:
    """Load files, resample to the model rate and cut windows; files too short are skipped,
    a file with holes (``joint_mask`` False, e.g. NaN in it) refused. No file long enough
    for one window: InputError, or None where windows are not ``required`` (validation).

    Augmentation for a small corpus (the augmented windows follow all the original ones):
    ``speeds``: every motion is also played at each of these speeds (``motion.resample.
    time_warp``; 1.0 is the motion as captured); ``mirror``: each of those also as its
    left-right mirror image. ``fraction`` < 1: only a seeded subset of whole files holding
    about that share of the frames (:func:`fraction_of`)."""
    motions = []
    for f in files:
        motion = load_training_motion(f)
        if motion.joint_mask is not None and not motion.joint_mask.all():
            holes = int((~motion.joint_mask).any(axis=1).sum())
            raise InputError(f"{f}: {holes} frame(s) with missing joints (NaN values or "
                             "joint_mask); the prior trains on complete takes only")  # fmt: skip
        motions.append(resample_motion(motion, MODEL_FPS))
        if on_file is not None:
            on_file(f)
    motions = [motions[i] for i in fraction_of(motions, fraction, fraction_seed)]
    variants = [(s, False) for s in speeds] + ([(s, True) for s in speeds] if mirror else [])
    variants.sort(key=lambda v: (v[0] != 1.0 or v[1], v[1]))  # the captured motion first
    jobs = [(speed, mirrored, m) for speed, mirrored in variants for m in motions]
    # filled in place, so that memory holds the windows once (not a list of pieces and
    # their concatenation: ~100,000 windows are 3.4 GB)
    out: WindowSet | None = None
    n = 0
    for speed, mirrored, motion in jobs:
        m = motion if speed == 1.0 else time_warp(motion, speed, MODEL_FPS)
        m = mirror_motion(m, body) if mirrored else m
        ws = motion_windows(m, body, length, stride)
        if ws is None:
            continue
        if out is None:
            total = sum(window_count(_frames(s, mo), length, stride) for s, _, mo in jobs)
            out = WindowSet(*(t.new_empty(total, *t.shape[1:]) for t in (ws.x0, ws.x, ws.betas)))
        for name in ("x0", "x", "betas"):
            getattr(out, name)[n : n + len(ws)] = getattr(ws, name)
        n += len(ws)
    if out is None and required:
        raise InputError(f"no motion of at least {length + 1} frames at {MODEL_FPS:g} Hz found")
    if out is None:
        return None
    return out.subset(torch.arange(n)) if n < len(out) else out


def window_count(num_frames: int, length: int, stride: int) -> int:
    """How many windows of ``length`` + 1 frames :func:`motion_windows` cuts every ``stride``."""
    return len(range(0, num_frames - length, stride)) if num_frames >= length + 1 else 0


def _frames(speed: float, motion: Motion) -> int:
    """Frames of ``motion`` (at the model rate) played at ``speed``, as ``time_warp`` samples."""
    if speed == 1.0:
        return motion.num_frames
    return len(resample_times(motion.num_frames, motion.fps * speed, MODEL_FPS))
