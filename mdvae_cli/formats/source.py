"""A motion on its own skeleton, as a BVH or ASF/AMC file describes it (``SourceMotion``), and
what every such reader shares: Euler angles, units guessed from stature, the limits past which a
value is corrupt, gzip-transparent text, resampling."""

from __future__ import annotations

import gzip
import math
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_regular
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations_np import quat_slerp, quat_to_rotmat, rotmat_to_quat
from mdvae_cli.motion.motion import MAX_ANGLE_DEG, MAX_DISTANCE_M

#: metres per CMU length unit (inches / 0.45); ASF ``:units length 0.45`` and cmuconvert BVH
CMU_UNIT = 0.0254 / 0.45


#: candidate length units for files that do not say (name, metres per unit)
_UNIT_GUESSES = (("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("in", 0.0254), ("cmu", CMU_UNIT))

#: BVH files also come in decimetres (MakeHuman)
BVH_UNIT_GUESSES = (*_UNIT_GUESSES, ("dm", 0.1))


def check_angles(radians: np.ndarray, what: str, path) -> None:
    """Refuse angle channels no exporter writes (|angle| > MAX_ANGLE_DEG).  radians: any shape"""
    if radians.size and np.abs(radians).max() > math.radians(MAX_ANGLE_DEG):
        worst = math.degrees(float(np.abs(radians).max()))
        raise InputError(
            f"{path}: {what} holds an angle of {worst:.3g} degrees; the file is corrupt "
            f"(angles over {MAX_ANGLE_DEG:g} degrees are refused)"
        )


@dataclass
class SourceMotion:
    """A mocap clip on its own skeleton.  J joints (end sites included), T frames.

    Attributes:
        names: J joint names (unique).
        parents: (J,) int parent index, -1 for the root (joint 0); parents precede children.
        offsets: (J, 3) rest offset of each joint from its parent, metres, world axes.
        rotations: (T, J, 3, 3) local rotations (identity for joints without rotation channels).
        root_positions: (T, 3) position of joint 0, metres.
        fps: frames per second.
        end_site: (J,) bool, True for BVH End Sites / ASF bone tips (no channels).
        info: what the file said (format, units, fps as written, dropped frames), for metadata.
        notes: remarks for the user.
        local_positions: (T, J, 3) per-frame offsets from the parent (metres, parent frame) for
            files whose non-root joints carry moving position channels (the SMPL FBX rig's
            pelvis); None when every offset is fixed.
        layout: what a writer needs to write the file again on its own skeleton (the parsed
            BVH, see ``formats.bvh_write.BvhLayout``); None when not kept.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    rotations: np.ndarray
    root_positions: np.ndarray
    fps: float
    end_site: np.ndarray
    info: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    local_positions: np.ndarray | None = None
    layout: object | None = None

    @property
    def num_frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def with_fps(self, fps: float) -> SourceMotion:
        """The same frames declared at another rate (e.g. CMU's 60 Hz captures labelled 120)."""
        return replace(self, fps=float(fps), info=dict(self.info), notes=list(self.notes))

    def check_distances(self, path) -> SourceMotion:
        """Refuse a root trajectory or bones beyond MAX_DISTANCE_M (a corrupt file, or a
        --scale far off). -> self"""
        for what, a in (("the root position", self.root_positions), ("a bone", self.offsets)):
            worst = float(np.abs(a).max()) if a.size else 0.0
            if worst > MAX_DISTANCE_M:
                raise InputError(f"{path}: {what} reaches {worst:.3g} m; the file is corrupt or "
                                 "its length unit is wrong (check --scale)")  # fmt: skip
        return self

    def rest_positions(self) -> np.ndarray:
        """Joint positions in the rest pose, root at the origin.  -> (J, 3)"""
        pos = np.zeros((self.num_joints, 3))
        for j in range(1, self.num_joints):
            pos[j] = pos[self.parents[j]] + self.offsets[j]
        return pos

    def forward_kinematics(self, frames: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (T, J, 3, 3) and positions (T, J, 3) of every joint (of ``frames``
        alone: a long take a chunk at a time)."""
        local = self.offsets if self.local_positions is None else self.local_positions[frames]
        return forward_kinematics(
            self.rotations[frames], local, self.parents, root=self.root_positions[frames]
        )


#: bytes a text mocap file (BVH, ASF, AMC) may hold, unzipped
MAX_TEXT = 256 << 20
#: the UTF-8 byte-order mark some Windows exporters put first
_BOM = b"\xef\xbb\xbf"
#: the first two bytes of every gzip stream
GZIP_MAGIC = b"\x1f\x8b"


def is_gzip_name(path: Path | str) -> bool:
    """Whether a file name ends in ``.gz``, in any case (``a.bvh.GZ``, ``c.Bvh.Gz``)."""
    return Path(path).suffix.lower() == ".gz"


def read_bytes(path: Path | str) -> bytes:
    """A text file's bytes, gunzipped when its name ends in ``.gz`` (any case) or its bytes
    start as gzip's do (a gzipped take named plain ``.bvh``); InputError when unreadable,
    over ``MAX_TEXT`` (unzipped) or binary."""
    path = Path(path)
    check_regular(path)
    gz = is_gzip_name(path)
    try:
        with open(path, "rb") as fh:
            gz = gz or fh.read(2) == GZIP_MAGIC
        opener = gzip.open if gz else open
        with opener(path, "rb") as fh:
            raw = fh.read(MAX_TEXT + 1)  # the limit holds while unzipping
    except (OSError, EOFError, zlib.error) as exc:
        gz = gz and not isinstance(exc, PermissionError)
        what = "not a readable .gz file" if gz else "cannot read"
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise InputError(f"{path}: {what} ({why})") from None
    if len(raw) > MAX_TEXT:
        raise InputError(f"{path}: over {MAX_TEXT >> 20} MiB of text (unzipped); a mocap take "
                         "is far smaller: split it, or check the file")  # fmt: skip
    if b"\0" in raw[:4096]:
        raise InputError(f"{path}: binary data, not a text mocap file")
    return raw


def read_text(path: Path | str, errors: str = "replace") -> str:
    """A text file's contents (:func:`read_bytes`) as UTF-8, a byte-order mark dropped.
    errors: how bytes that are not UTF-8 are decoded ("surrogateescape" keeps them, so that
    text written back with the same setting has the file's bytes)."""
    return read_bytes(path).removeprefix(_BOM).decode("utf-8", errors=errors)


def decode_text(raw: bytes) -> tuple[str, str]:
    """Bytes as text and the encoding that gives the same bytes back: ``"utf-8-sig"`` (UTF-8
    after a byte-order mark, which is not in the text), ``"utf-8"``, else ``"latin-1"`` (every
    byte one character: a cp1252 or latin-1 file's names read as their own letters, most of
    them, and come back byte for byte)."""
    if raw.startswith(_BOM):
        try:
            return raw[len(_BOM) :].decode("utf-8"), "utf-8-sig"
        except UnicodeDecodeError:
            pass
    try:
        return raw.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return raw.decode("latin-1"), "latin-1"


def read_text_encoded(path: Path | str) -> tuple[str, str]:
    """A text file's contents (:func:`read_bytes`) and their encoding (:func:`decode_text`),
    for files written back with their own header."""
    return decode_text(read_bytes(path))


def guess_length_unit(
    height: float, candidates: tuple[tuple[str, float], ...] = _UNIT_GUESSES, target: float = 1.7
) -> tuple[str, float]:
    """The unit (name, metres per unit) among ``candidates`` that makes a skeleton ``height``
    units tall closest to ``target`` metres (log scale): metres, cm, mm, inches or CMU units."""
    if not height > 0:
        return "m", 1.0
    return min(candidates, key=lambda u: abs(math.log(height * u[1] / target)))


def skeleton_height(offsets: np.ndarray, parents: np.ndarray) -> float:
    """Largest extent of the rest-pose joints along any axis, in file units."""
    pos = np.zeros_like(offsets)
    for j in range(1, len(parents)):
        pos[j] = pos[parents[j]] + offsets[j]
    return float((pos.max(0) - pos.min(0)).max())


def resample_source(src: SourceMotion, fps: float) -> SourceMotion:
    """Resample to ``fps``: slerp on local rotations, lerp on the root.

    Output frames are 1/fps apart from the first frame and never run past the last one.
    """
    if abs(src.fps - fps) < 1e-9:
        return src
    T = src.num_frames
    n_out = int(math.floor((T - 1) / src.fps * fps + 1e-6)) + 1
    t = np.arange(n_out) * (src.fps / fps)
    i0 = np.clip(np.floor(t + 1e-9).astype(int), 0, T - 1)
    i1 = np.clip(i0 + 1, 0, T - 1)
    w = np.clip(t - i0, 0.0, 1.0)
    rot = src.rotations[i0].copy()
    root = src.root_positions[i0] * (1 - w[:, None]) + src.root_positions[i1] * w[:, None]
    local = src.local_positions
    if local is not None:
        local = local[i0] * (1 - w[:, None, None]) + local[i1] * w[:, None, None]
    mid = np.flatnonzero(w > 1e-9)  # frames between two source frames (none for 120 -> 30)
    if len(mid):
        q0 = rotmat_to_quat(src.rotations[i0[mid]])
        q1 = rotmat_to_quat(src.rotations[i1[mid]])
        rot[mid] = quat_to_rotmat(quat_slerp(q0, q1, w[mid, None]))
    out = replace(src, rotations=rot, root_positions=root, fps=float(fps), info=dict(src.info),
                  notes=list(src.notes), local_positions=local, layout=None)  # fmt: skip
    return out
