"""A BVH take's local joint rotations made from its Euler channels, a chunk of frames at a
time when asked (:class:`ChannelRotations`: what the reader gives a take), by the retarget's
solve and by the way back; and any take's rotations turned to other axes or another rest pose
when asked (:class:`TurnedRotations`)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.geometry.euler import euler_to_rotmat

if TYPE_CHECKING:
    from mdvae_cli.formats.bvh import BvhLayout


def channel_rotations(layout: BvhLayout, data: np.ndarray, num_joints: int) -> np.ndarray:
    """The local rotations of some of the file's rows, from their Euler channels (identity
    for a joint without rotation channels).  data: (n, C) rows -> (n, J, 3, 3)"""
    out = np.broadcast_to(np.eye(3), (data.shape[0], num_joints, 3, 3)).copy()
    for j in range(num_joints):
        rot = layout.joint_columns(j, "r")
        if rot:
            out[:, j] = euler_to_rotmat(np.deg2rad(data[:, [c for c, _ in rot]]),
                                        "".join(a for _, a in rot))  # fmt: skip
    return out


class RotationsWhenAsked:
    """Local rotations (T, J, 3, 3) made for the frames asked for, none held: indexed by
    frames first (then anything else) they give an array, ``np.asarray`` gives all of them.
    A subclass makes those of some frames (:meth:`made`)."""

    ndim = 4
    dtype = np.dtype(np.float64)
    shape: tuple[int, int, int, int]

    def made(self, frames) -> np.ndarray:
        """The rotations of ``frames`` (an index array or slice -> (n, J, 3, 3); one index ->
        (J, 3, 3))."""
        raise NotImplementedError

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        frames, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        out = self.made(frames)
        one = not isinstance(frames, slice) and np.ndim(frames) == 0  # (J, 3, 3)
        return out[rest] if one else out[(slice(None), *rest)]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self[:]
        return out if dtype is None else out.astype(dtype)


class ChannelRotations(RotationsWhenAsked):
    """A BVH take's local rotations, made from its channels (:func:`channel_rotations`) each
    time frames are asked for instead of held: what the reader gives a take
    (``formats.bvh.load_bvh``) and a retargeted take keeps for its way back
    (:func:`let_go_of_rotations`; the array is 373 MB on a 30-minute 120 Hz take of 24
    joints)."""

    def __init__(self, layout: BvhLayout, num_joints: int):
        self.layout, self.num_joints = layout, num_joints

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (len(self.layout.rows), self.num_joints, 3, 3)

    def made(self, frames) -> np.ndarray:
        rows = self.layout.rows[frames]
        out = channel_rotations(self.layout, self.layout.data[np.atleast_1d(rows)],
                                self.num_joints)  # fmt: skip
        return out[0] if np.ndim(rows) == 0 else out


class TurnedRotations(RotationsWhenAsked):
    """Another set of local rotations, each joint's turned on both sides: ``left[j] @ R[t, j]
    @ right[j]^T``, made when frames are asked for (a take's rest pose or world axes changed,
    ``retarget.joint_map.canonicalise`` and ``retarget.upright.rerest``, without an array the
    size of the take: 373 MB on a 30-minute 120 Hz take of 24 joints). ``base``: an array or
    :class:`RotationsWhenAsked`; left, right: (J, 3, 3)."""

    def __init__(self, base, left: np.ndarray, right: np.ndarray):
        self.base = base
        self.left = np.asarray(left, dtype=np.float64)
        self.right = np.asarray(right, dtype=np.float64)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return tuple(self.base.shape)  # type: ignore[return-value]

    def made(self, frames) -> np.ndarray:
        R = np.asarray(self.base[frames], dtype=np.float64)  # (J, 3, 3) or (n, J, 3, 3)
        return self.left @ R @ np.swapaxes(self.right, -1, -2)


def let_go_of_rotations(src: SourceMotion) -> SourceMotion:
    """``src`` (a BVH take read by :func:`load_bvh`, whose rotations the retarget may have
    made an array: a turned or re-rested take) with its rotations made from the channels
    when asked (:class:`ChannelRotations`) instead of held; any other take as it is."""
    from mdvae_cli.formats.bvh import BvhLayout

    layout = src.layout
    if not isinstance(layout, BvhLayout) or isinstance(src.rotations, ChannelRotations):
        return src
    if len(layout.rows) != src.num_frames:
        return src
    return replace(src, rotations=ChannelRotations(layout, src.num_joints))
