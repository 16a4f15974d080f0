"""Training data: motion files (and split files) -> canonical state windows (x0, x_1..x_T) at
the model rate."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import expand_inputs
from mdvae_cli.motion.chunks import MODEL_FPS, chunk_states, motion_to_params
from mdvae_cli.motion.mirror import mirror_motion
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.npz_io import load_motion
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.motion.state import BodyParams


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
    files = [f for f, _ in expand_inputs(data)]
    if split_file is not None:
        wanted = {p.resolve() for p in read_split(split_file).get(split, [])}
        return [f for f in files if f.resolve() in wanted]
    every = max(2, round(1 / val_fraction))
    if split == "val":
        return files[::every]
    return [f for i, f in enumerate(files) if i % every != 0]


def outside(files: list[Path], folder: Path) -> list[Path]:
    """``files`` less those inside ``folder`` (e.g. a run folder kept among the data)."""
    root = Path(folder).resolve()
    return [f for f in files if not Path(f).resolve().is_relative_to(root)]


def load_windows(
    files: list[Path],
    body: BodyModel,
    length: int,
    stride: int,
    on_file: Callable[[Path], None] | None = None,
    mirror: bool = False,
) -> WindowSet:
    """Load files, resample to the model rate and cut windows; files too short are skipped.

    ``mirror``: also cut windows from each motion's left-right mirror image (twice the
    windows; data augmentation for a small corpus). The mirrored windows follow all the
    original ones."""
    sets, mirrored = [], []
    for f in files:
        motion = resample_motion(load_motion(f), MODEL_FPS)
        ws = motion_windows(motion, body, length, stride)
        if ws is not None:
            sets.append(ws)
            if mirror:
                mirrored.append(motion_windows(mirror_motion(motion, body), body, length, stride))
        if on_file is not None:
            on_file(f)
    if not sets:
        raise InputError(f"no motion of at least {length + 1} frames at {MODEL_FPS:g} Hz found")
    return WindowSet.concat(sets + mirrored)
