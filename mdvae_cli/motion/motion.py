"""The Motion dataclass: one SMPL-family motion clip in numpy."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mdvae_cli.body.data import NUM_BODY_JOINTS
from mdvae_cli.errors import InputError

#: AMASS ``poses`` widths we read, and the layout name of each.
POSE_WIDTHS = {156: "smplh", 165: "smplx", 72: "smpl", 66: "body"}
#: no file holds an angle this large (degrees), a root this far from the origin or a bone this
#: long (metres), or a body shape coefficient this large: a value past one is corrupt
MAX_ANGLE_DEG = 1e5
MAX_DISTANCE_M = 1e4
MAX_BETA = 1e3
#: the frame rates (Hz) a motion may have: outside is a mistake (e.g. a frame time stored as the
#: rate, 1/120), and resampling it to 30 Hz would make hours of frames, or none
FPS_RANGE = (1.0, 10_000.0)


def check_fps(fps: float, where: str, swapped: str = "", remedy: str = "") -> float:
    """``fps`` when it lies in FPS_RANGE, else InputError naming ``where`` (a file, an option).
    ``swapped``: a question the message asks when 1/fps would lie in it (e.g. "is
    mocap_framerate a frame time?"), followed by ``remedy`` (what to do then)."""
    low, high = FPS_RANGE
    if low <= fps <= high:
        return fps
    hint = ""
    if swapped and fps > 0 and low <= 1 / fps <= high:
        hint = f"; {swapped} (1/{fps:.6g} = {1 / fps:.3g} Hz){'; ' + remedy if remedy else ''}"
    raise InputError(
        f"{where}: frame rate {fps:.6g} Hz is implausible ({low:g} to {high:g} Hz){hint}"
    )


@dataclass
class Motion:
    """One motion clip. T frames.

    Attributes:
        root_orient: (T, 3) global orientation, axis-angle.
        pose_body: (T, 21, 3) body-joint axis-angles (SMPL joints 1..21).
        trans: (T, 3) root translation, metres, z-up (AMASS convention).
        betas: (S,) body shape, as many coefficients as the file had.
        fps: frames per second, > 0.
        pose_extra: (T, K) the rest of ``poses`` after the 66 body columns (hands, jaw, eyes),
            carried through untouched; K = poses width - 66.
        gender: "neutral", "male" or "female" (as the file says).
        joint_mask: (T, 22) bool, True where a body joint was observed; None = all observed.
        extras: other keys of the source file, written back unchanged.
        layout: how the source stored things (fps key, gender as bytes), to write the same way.
        notes: remarks made while reading (padded betas, missing keys) for the user; one that
            starts with ``warning: `` says the output will differ from the file (a renamed key).
    """

    root_orient: np.ndarray
    pose_body: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    fps: float
    pose_extra: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    gender: str = "neutral"
    joint_mask: np.ndarray | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    layout: dict[str, object] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        T = np.shape(self.root_orient)[0] if np.ndim(self.root_orient) else 0
        self.pose_extra = frame_rows(self.pose_extra, int(T))

    @property
    def num_frames(self) -> int:
        return int(self.root_orient.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    @property
    def poses(self) -> np.ndarray:
        """(T, 66 + K) the AMASS ``poses`` array."""
        T = self.num_frames
        return np.concatenate(
            [self.root_orient, self.pose_body.reshape(T, (NUM_BODY_JOINTS - 1) * 3),
             self.pose_extra.reshape(T, -1)], axis=1,
        )  # fmt: skip

    @property
    def joint_rotations(self) -> np.ndarray:
        """The pelvis's and the body joints' axis-angles in one array, pelvis first.
        -> (T, 22, 3)"""
        return self.joint_rotations_at(slice(None))

    def joint_rotations_at(self, frames) -> np.ndarray:
        """:attr:`joint_rotations` of some frames only (a slice or index array; the others
        are not copied).  -> (n, 22, 3)"""
        return np.concatenate([self.root_orient[frames][:, None], self.pose_body[frames]], axis=1)

    def with_body(self, root_orient=None, pose_body=None, trans=None, pose_extra=None) -> Motion:
        """A copy with some body parameters replaced. A new frame count needs ``pose_extra``
        for the new frames too, where the motion has hands (else InputError: they are never
        dropped silently)."""
        root_orient = self.root_orient if root_orient is None else root_orient
        if pose_extra is None:
            pose_extra = self.pose_extra
            T = len(root_orient)
            if T != self.num_frames and pose_extra.shape[1]:
                raise InputError(
                    f"with_body changes the frame count ({self.num_frames} -> {T}) of a motion "
                    "with hands: pass pose_extra= for the new frames"
                )
            if T != self.num_frames:
                pose_extra = np.zeros((T, 0))
        return replace(
            self,
            root_orient=root_orient,
            pose_body=self.pose_body if pose_body is None else pose_body,
            trans=self.trans if trans is None else trans,
            pose_extra=pose_extra,
            extras=dict(self.extras),
            layout=dict(self.layout),
            notes=list(self.notes),
        )

    @staticmethod
    def from_poses(
        poses: np.ndarray, trans: np.ndarray, betas: np.ndarray, fps: float, **kwargs
    ) -> Motion:
        """Split an AMASS ``poses`` array (T, W) with W >= 66 into a Motion (numpy arrays or
        torch tensors, copied). ``formats.npz_io.motion_from_arrays`` checks every value too
        and reads NaN as holes."""
        poses, trans, betas = as_numpy(poses), as_numpy(trans), as_numpy(betas)
        if poses.ndim != 2 or poses.shape[1] < 66:
            raise InputError(f"poses has shape {poses.shape}, expected (T, 66 + K)")
        T = poses.shape[0]
        return Motion(
            root_orient=poses[:, :3].copy(),
            pose_body=poses[:, 3:66].reshape(T, NUM_BODY_JOINTS - 1, 3).copy(),
            trans=np.asarray(trans, dtype=np.float64).copy(),
            betas=np.asarray(betas, dtype=np.float64).copy(),
            fps=float(fps),
            pose_extra=poses[:, 66:].copy(),
            **kwargs,
        )


def frame_rows(pose_extra, T: int) -> np.ndarray:
    """``pose_extra`` as (T, K) rows: None or an empty array (no hands, jaw or eyes) becomes
    (T, K) zeros, K its column count (0 for None, a 1-D or the default (0, 0) array); one with
    values must have T rows, else InputError (one line): no hands are dropped silently."""
    if pose_extra is None:
        return np.zeros((T, 0))
    if np.size(pose_extra) == 0:
        width = np.shape(pose_extra)[1] if np.ndim(pose_extra) == 2 else 0
        return pose_extra if np.shape(pose_extra) == (T, width) else np.zeros((T, width))
    if np.ndim(pose_extra) < 2 or np.shape(pose_extra)[0] != T:
        raise InputError(
            f"pose_extra has shape {np.shape(pose_extra)}, expected ({T}, K): one row of hand, "
            "jaw and eye axis-angles per frame (np.tile(row, (T, 1)) repeats one)"
        )
    return pose_extra


def as_numpy(x) -> np.ndarray:
    """A numpy array of ``x``: an array, a list, or a torch tensor (detached, on the CPU)."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # a torch tensor, without importing torch
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def check_motion(motion: Motion) -> None:
    """InputError (one line) unless ``motion`` is one a denoise can read: root_orient (T, 3),
    pose_body (T, 21, 3), trans (T, 3), pose_extra (T, K), joint_mask (T, 22) or None, all
    real and finite, T >= 1, and a frame rate in FPS_RANGE."""
    T = np.shape(motion.root_orient)[0] if np.ndim(motion.root_orient) else 0
    shapes = {"root_orient": (T, 3), "pose_body": (T, NUM_BODY_JOINTS - 1, 3), "trans": (T, 3)}
    for name, shape in shapes.items():
        arr = getattr(motion, name)
        if np.shape(arr) != shape:
            raise InputError(f"{name} has shape {np.shape(arr)}, expected {shape}")
        kind = np.asarray(arr).dtype.kind
        if kind not in "iuf":
            raise InputError(f"{name} is not real numbers (dtype {np.asarray(arr).dtype})")
        bad = ~np.isfinite(arr).reshape(T, -1).all(axis=1)
        if bad.any():
            raise InputError(
                f"{name} holds NaN or infinite values in {int(bad.sum())} frame(s), the first "
                f"{int(np.argmax(bad))}; mark holes in joint_mask with finite values "
                "(formats.npz_io.motion_from_arrays reads NaN as holes)"
            )
    if T < 1:
        raise InputError("the motion has no frames")
    if np.ndim(motion.pose_extra) != 2 or len(motion.pose_extra) != T:
        raise InputError(f"pose_extra has shape {np.shape(motion.pose_extra)}, expected ({T}, K)")
    if motion.joint_mask is not None and np.shape(motion.joint_mask) != (T, NUM_BODY_JOINTS):
        raise InputError(
            f"joint_mask has shape {np.shape(motion.joint_mask)}, expected ({T}, {NUM_BODY_JOINTS})"
        )
    try:
        fps = float(motion.fps)
    except (TypeError, ValueError):
        raise InputError(f"fps must be a number, got {motion.fps!r}") from None
    check_fps(fps, "fps")


def check_motions(motions) -> list[Motion]:
    """``motions`` as a list, each checked (:func:`check_motion`); a one-line InputError
    names the first bad one by its index, a TypeError anything that is not a list of Motion."""
    if isinstance(motions, Motion):
        raise TypeError("expected a list of motions, got one Motion: pass [motion]")
    motions = list(motions)
    for i, motion in enumerate(motions):
        if not isinstance(motion, Motion):
            raise TypeError(f"motion {i} is a {type(motion).__name__}, not a Motion")
        try:
            check_motion(motion)
        except InputError as exc:
            raise InputError(f"motion {i}: {exc}") from None
    return motions


#: arrays a result shares with its input are copied under this many bytes, viewed read-only
#: above it (a long take's per-frame arrays)
_COPY_BELOW = 1 << 20


def unshared(result: Motion, source: Motion) -> Motion:
    """``result`` with each array it shares with ``source`` (hands, betas, extras carried
    through) copied, or one of a long take's size (:data:`_COPY_BELOW`) as a read-only view,
    so that changing one in place cannot change the other (it raises) and a 30-minute 120 Hz
    take's hands (155 MB) are not copied."""

    def guarded(mine, theirs):
        if (
            isinstance(mine, np.ndarray)
            and theirs is not None
            and np.may_share_memory(mine, theirs)
        ):
            if mine.nbytes < _COPY_BELOW:
                return mine.copy()
            view = mine.view()
            view.flags.writeable = False
            return view
        return mine

    names = ("root_orient", "pose_body", "trans", "betas", "pose_extra", "joint_mask")
    fields = {n: guarded(getattr(result, n), getattr(source, n)) for n in names}
    extras = {k: guarded(v, source.extras.get(k)) for k, v in result.extras.items()}
    if all(fields[n] is getattr(result, n) for n in names) and all(
        extras[k] is v for k, v in result.extras.items()
    ):
        return result
    return replace(result, extras=extras, **fields)


def slice_frames(motion: Motion, start: int, stop: int) -> Motion:
    """Frames [start, stop) of a motion as a new Motion; per-frame extra arrays (first dim T,
    numeric) are sliced too, the others kept; notes are not carried."""
    T = motion.num_frames
    sl = slice(start, stop)
    extras = {
        k: (v[sl].copy() if v.ndim >= 1 and v.shape[0] == T and v.dtype.kind in "biuf" else v)
        for k, v in motion.extras.items()
    }
    return replace(
        motion,
        root_orient=motion.root_orient[sl].copy(),
        pose_body=motion.pose_body[sl].copy(),
        trans=motion.trans[sl].copy(),
        pose_extra=motion.pose_extra[sl].copy(),
        joint_mask=None if motion.joint_mask is None else motion.joint_mask[sl].copy(),
        extras=extras,
        layout=dict(motion.layout),
        notes=[],
    )
