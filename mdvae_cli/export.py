"""Motion -> posed body meshes -> one ``.ply`` / ``.obj`` file per frame (via trimesh).

:func:`pose_motion_chunks` turns a Motion into body-model outputs a chunk of frames at a time
(bounded memory); evaluation reuses it. :func:`export_mesh_sequence` writes the meshes.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, BodyModelData
from mdvae_cli.body.skinning import BodyModel, BodyOutput
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.motion.motion import Motion

#: mesh file formats :func:`export_mesh_sequence` writes
MESH_FORMATS = ("ply", "obj")

#: frames posed at once; a full SMPL mesh chunk of 256 frames needs ~100 MB of float32 work space
DEFAULT_CHUNK_FRAMES = 256


def as_body_model(body: BodyModel | BodyModelData) -> BodyModel:
    """Wrap model arrays in a :class:`BodyModel` (float32, CPU); pass a BodyModel through."""
    if isinstance(body, BodyModel):
        return body
    return BodyModel(body)


#: columns of the hand joints (15 left, 15 right) in SMPL-H and SMPL-X poses past the body
HAND_COLUMNS = 90


def extra_pose(pose_extra: np.ndarray, n_extra: int) -> np.ndarray | None:
    """A motion's pose past the body as a model with ``n_extra`` such joints reads it, or None
    (its rest pose) when the layouts share nothing.  (T, K) -> (T, 3 n_extra)

    The same layout is taken as it is; the hands go across SMPL-H (30 hand joints) and SMPL-X
    (jaw and eyes, then the same 30 hand joints), the face at rest on an SMPL-X model.
    """
    width = pose_extra.shape[1]
    if n_extra == 0 or width == 3 * n_extra:
        return pose_extra if n_extra else None
    if width == HAND_COLUMNS and 3 * n_extra > HAND_COLUMNS:  # SMPL-H hands on SMPL-X
        face = np.zeros((len(pose_extra), 3 * n_extra - HAND_COLUMNS))
        return np.concatenate([face, pose_extra], axis=1)
    if 3 * n_extra == HAND_COLUMNS and width > HAND_COLUMNS:  # SMPL-X hands on SMPL-H
        return pose_extra[:, width - HAND_COLUMNS :]
    return None


def pose_motion_chunks(
    motion: Motion,
    body: BodyModel | BodyModelData,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    vertices: bool = True,
    betas: np.ndarray | None = None,
    frames: Iterable[int] | None = None,
) -> Iterator[tuple[np.ndarray, BodyOutput]]:
    """Pose ``motion`` with ``body`` a chunk of frames at a time.

    betas: (S,) shape to use instead of the motion's own (e.g. the ground truth's).
    frames: the frame indices to pose (default all T), in order.
    Yields ``(indices (C,), BodyOutput)`` with joints (C, 22, 3), markers (C, M, 3) and, when
    ``vertices``, vertices (C, V, 3), in metres. Hand/face joints take ``motion.pose_extra``
    as the model's layout reads it (:func:`extra_pose`), else the rest pose.
    """
    if chunk_frames < 1:
        raise InputError(f"chunk_frames must be >= 1, got {chunk_frames}")
    model = as_body_model(body)
    dtype = model.v_template.dtype
    device = model.v_template.device
    index = np.arange(motion.num_frames) if frames is None else np.asarray(list(frames), int)
    shape = torch.as_tensor(motion.betas if betas is None else betas, dtype=dtype, device=device)
    n_extra = model.num_joints - NUM_BODY_JOINTS
    pose_extra = extra_pose(motion.pose_extra, n_extra)

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)

    for start in range(0, len(index), chunk_frames):
        ids = index[start : start + chunk_frames]
        extra = None
        if pose_extra is not None:
            extra = tensor(pose_extra[ids]).reshape(len(ids), n_extra, 3)
        with torch.no_grad():  # not around the yield: grad mode must not leak to the caller
            out = model(
                tensor(motion.root_orient[ids]),
                tensor(motion.pose_body[ids]),
                tensor(motion.trans[ids]),
                shape,
                pose_extra=extra,
                vertices=vertices,
            )
        yield ids, out


def export_mesh_sequence(
    motion: Motion,
    body: BodyModel | BodyModelData,
    out_dir: Path | str,
    fmt: str = "ply",
    every: int = 1,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    forbid: Iterable[Path] = (),
    progress: Callable[[int], None] | None = None,
    span: tuple[int, int | None] = (0, None),
) -> list[Path]:
    """Write the posed mesh of every ``every``-th frame to ``out_dir/frame_NNNNNN.<fmt>``.

    NNNNNN is the source frame index (0-based, six digits), so ``every=2`` writes frame_000000,
    frame_000002, ... ``span``: only frames start <= t < stop (:func:`frame_span`; stop None or
    past the end: to the end), every ``every``-th from start; InputError when it holds none.
    Each file is written to a temporary name and renamed; ``forbid`` lists files never to
    overwrite. Once every frame is written, ``frame_NNNNNN.<fmt>`` files that an
    earlier export left in the folder (a longer take, another ``every``) are removed, so that
    the folder holds this sequence and no stale tail. ``progress(n)`` is called after each chunk
    with the number of files just written. Returns the written paths, in frame order.
    """
    fmt = fmt.lower().lstrip(".")
    if fmt not in MESH_FORMATS:
        raise InputError(f"unknown mesh format {fmt!r}; choose one of {', '.join(MESH_FORMATS)}")
    if every < 1:
        raise InputError(f"--every must be >= 1, got {every}")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir} exists and is not a folder")
    from mdvae_cli.model.checkpoint import interrupts_deferred

    # heavy, only needed here; trimesh's own optional imports catch BaseException, so a
    # Ctrl-C or SIGTERM that lands while it loads would be swallowed: held, raised after
    with interrupts_deferred():
        import trimesh

    model = as_body_model(body)
    faces = np.asarray(model.data.faces, dtype=np.int64)
    forbid = tuple(Path(p) for p in forbid)
    start, stop = span
    frames = range(start, motion.num_frames if stop is None else min(stop, motion.num_frames),
                   every)  # fmt: skip
    if not frames:
        raise InputError(f"--frames {start}:{'' if stop is None else stop} holds no frame of "
                         f"this take (frames 0 to {motion.num_frames - 1})")  # fmt: skip
    written: list[Path] = []
    # every frame goes to a hidden staging folder first and is moved in at the end: a failure
    # or Ctrl-C part way leaves no frames behind (and no folder that was made for them)
    staging = out_dir / f".mdvae-partial-{secrets.token_hex(6)}"
    made = [p for p in (out_dir, *out_dir.parents) if not p.exists()]
    try:
        chunks = pose_motion_chunks(motion, model, chunk_frames, vertices=True, frames=frames)
        for ids, out in chunks:
            verts = out.vertices.double().cpu().numpy()
            for t, v in zip(ids, verts, strict=True):
                mesh = trimesh.Trimesh(vertices=v, faces=faces, process=False)
                path = out_dir / f"frame_{int(t):06d}.{fmt}"
                _refuse_input(path, forbid)
                write_atomic(staging / path.name, lambda tmp, m=mesh: m.export(tmp, file_type=fmt))
                written.append(path)
            if progress is not None:
                progress(len(ids))
        for path in written:
            os.replace(staging / path.name, path)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        for folder in made:  # deepest first, only while empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    with contextlib.suppress(OSError):
        staging.rmdir()
    remove_stale_frames(out_dir, fmt, written)
    return written


def frame_span(text: str) -> tuple[int, int | None]:
    """``--frames``: ``"START:STOP"`` (0-based frame numbers, STOP not included; either may be
    left out: ``"120:"``, ``":90"``) -> (start, stop or None). InputError in the user's words."""
    first, colon, last = text.strip().partition(":")
    try:
        if not colon:
            raise ValueError
        start = int(first) if first.strip() else 0
        stop = int(last) if last.strip() else None
    except ValueError:
        raise InputError(f"--frames {text!r}: give START:STOP, e.g. 120:240 or 120:") from None
    if start < 0 or (stop is not None and stop <= start):
        raise InputError(f"--frames {text!r}: START must be 0 or more and STOP after it")
    return start, stop


def _refuse_input(path: Path, forbid: tuple[Path, ...]) -> None:
    """InputError when ``path`` is one of the input files ``forbid``."""
    for p in forbid:
        if p.exists() and p.resolve() == path.resolve():
            raise InputError(f"refusing to overwrite the input file {p}")


def remove_stale_frames(out_dir: Path, fmt: str, keep: list[Path]) -> int:
    """Delete ``frame_NNNNNN.<fmt>`` files in ``out_dir`` other than ``keep`` (what an earlier
    export into the folder left). Other files are never touched. -> how many were removed"""
    pattern = re.compile(rf"frame_\d{{6}}\.{re.escape(fmt)}")
    kept = {p.name for p in keep}
    stale = [
        p
        for p in out_dir.glob(f"frame_*.{fmt}")
        if p.is_file() and pattern.fullmatch(p.name) and p.name not in kept
    ]
    for p in stale:
        p.unlink()
    return len(stale)
