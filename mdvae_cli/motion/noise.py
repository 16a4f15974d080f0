"""Synthetic corruption of clean motions: the Pose-NDF noise protocol, plus missing joints.

The Pose-NDF protocol (used for Motion-DVAE's noisy-AMASS experiments) adds zero-mean Gaussian
noise of standard deviation ``sigma`` (radians) to every axis-angle component of the 21 body
joints; the root orientation, the translation and the hand/face joints are left as they are.

Three optional extras, off by default:

* **translation jitter** (``trans_sigma``, metres): zero-mean Gaussian noise added to ``trans``,
  independently per frame and per axis. The file holds body parameters, not joint positions,
  so this is the one positional noise that can be stored without inventing new arrays: it moves
  every joint (and vertex) of a frame by the same random offset of ``trans_sigma`` per axis.
* **missing joints** (``drop_frac``): exactly ``round(drop_frac * T * 22)`` (frame, joint)
  entries, drawn uniformly without replacement, are marked unobserved in ``joint_mask``
  (``(T, 22)`` bool, True = observed). The poses themselves are not changed.
* **spikes** (``spike_frac``, ``spike_rad``): outliers such as a swapped marker or a solver
  flip. Each (frame, body joint) entry is hit independently with probability ``spike_frac``,
  and a hit adds zero-mean Gaussian noise of std ``spike_rad`` to each of its three axis-angle
  components, on top of the protocol's noise.

Randomness comes only from the ``numpy.random.Generator`` passed in. It is split into one
independent stream per kind of noise, so turning on jitter or drops does not change the pose
noise drawn for the same generator seed.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import PurePath

import numpy as np

from mdvae_cli.body.data import NUM_BODY_JOINTS
from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import Motion


@dataclass(frozen=True)
class NoiseSettings:
    """What :func:`add_pose_noise` applies.

    sigma: std of the axis-angle noise on the 21 body joints, radians, >= 0.
    trans_sigma: std of the per-frame, per-axis translation jitter, metres, >= 0.
    drop_frac: fraction of (frame, joint) entries to mark missing, in [0, 1].
    spike_frac: probability that a (frame, body joint) entry gets a spike, in [0, 1].
    spike_rad: std of a spike per axis-angle component, radians, >= 0.
    """

    sigma: float
    trans_sigma: float = 0.0
    drop_frac: float = 0.0
    spike_frac: float = 0.0
    spike_rad: float = 0.0

    def validate(self) -> NoiseSettings:
        """Raise InputError naming the first out-of-range value."""
        for name in ("sigma", "trans_sigma", "spike_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"{name} must be a finite number >= 0, got {value:g}")
        for name in ("drop_frac", "spike_frac"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise InputError(f"{name} must be between 0 and 1, got {value:g}")
        return self


def add_pose_noise(
    motion: Motion,
    sigma: float,
    rng: np.random.Generator | int,
    trans_sigma: float = 0.0,
    drop_frac: float = 0.0,
    spike_frac: float = 0.0,
    spike_rad: float = 0.0,
) -> Motion:
    """A noisy copy of ``motion`` (the input is not modified).

    pose_body (T, 21, 3) += N(0, sigma^2) per component; trans (T, 3) += N(0, trans_sigma^2)
    per component when ``trans_sigma`` > 0; joint_mask (T, 22) gets ``drop_frac`` of its entries
    set False when ``drop_frac`` > 0 (combined with any existing mask); pose_body entries get
    spikes when ``spike_frac`` > 0. root_orient, pose_extra, betas and fps are copied unchanged.
    See the module docstring for the exact protocol.
    """
    NoiseSettings(*map(float, (sigma, trans_sigma, drop_frac, spike_frac, spike_rad))).validate()
    rng = np.random.default_rng(rng)  # a seed too; a Generator as it is
    pose_rng, trans_rng, drop_rng = rng.spawn(3)
    T = motion.num_frames

    pose_body = motion.pose_body + pose_rng.normal(0.0, sigma, size=motion.pose_body.shape)
    if spike_frac > 0:  # a stream of its own, spawned after the others: they stay the same
        spike_rng = rng.spawn(1)[0]
        hit = spike_rng.random(pose_body.shape[:-1]) < spike_frac
        pose_body[hit] += spike_rng.normal(0.0, spike_rad, size=(int(hit.sum()), 3))
    trans = motion.trans.copy()
    if trans_sigma > 0:
        trans = trans + trans_rng.normal(0.0, trans_sigma, size=trans.shape)
    noisy = motion.with_body(pose_body=pose_body, trans=trans)

    if drop_frac > 0:
        n_entries = T * NUM_BODY_JOINTS
        n_drop = int(round(drop_frac * n_entries))
        observed = np.ones(n_entries, dtype=bool)
        observed[drop_rng.choice(n_entries, size=n_drop, replace=False)] = False
        observed = observed.reshape(T, NUM_BODY_JOINTS)
        if motion.joint_mask is not None:
            observed &= motion.joint_mask.astype(bool)
        noisy.joint_mask = observed
    elif motion.joint_mask is not None:
        noisy.joint_mask = motion.joint_mask.copy()
    return noisy


def file_rng(seed: int, relative_path: PurePath | str) -> np.random.Generator:
    """A generator for one file of a batch, fixed by ``seed`` and the file's relative path.

    The same (seed, path) always gives the same stream, on any machine and whatever the order
    or number of files processed; different paths give independent streams.
    """
    if int(seed) < 0:
        raise InputError(f"seed must be >= 0, got {seed}")
    name = PurePath(relative_path).as_posix().encode("utf-8")
    digest = hashlib.sha256(name).digest()
    words = [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.default_rng(np.random.SeedSequence([int(seed), *words]))


# --------------------------------------------------------------------------------------------
# video-like noise (``mdvae add-noise --preset video``; docs/model.md, "Video-like noise")

#: the leg joints of ``pose_body`` (SMPL joints 1..21 minus one) that a left/right swap
#: exchanges: hips, knees, ankles, feet, left then right
_LEFT_LEG, _RIGHT_LEG = (0, 3, 6, 9), (1, 4, 7, 10)
_MIRROR = np.array([1.0, -1.0, -1.0])  # a joint's rotation reflected through x = 0


@dataclass(frozen=True)
class VideoNoise:
    """What a monocular video pose estimator gets wrong, as noise on clean motion.

    Each noise has a white part (independent per frame) and a slow part (white noise smoothed
    over ``slow_time`` seconds, a smooth signal of the std given): the slow part is the
    estimator's pose-dependent bias, which stays for a while, the white part its jitter.

    pose_white, pose_slow: std of each body-joint axis-angle component, rad.
    root_white, root_slow: the same on the root orientation, rad.
    depth_white, depth_slow: translation noise along the camera's viewing direction (a random
        horizontal direction per clip), m; lateral_white, lateral_slow: on the two other axes.
    swap_rate: left/right leg swaps per second, each lasting 1..``swap_frames`` frames (the
        legs' rotations exchanged and mirrored); turn_rate: 180-degree turns of the root about
        the vertical per second (the person seen from the wrong side), 1..``swap_frames``.
    spike_frac, spike_rad: per (frame, body joint) probability of a spike, and its std, rad.
    slow_time: time scale of the slow parts (std of the Gaussian that smooths them), s.
    """

    pose_white: float = 0.01
    pose_slow: float = 0.10
    root_white: float = 0.005
    root_slow: float = 0.05
    depth_white: float = 0.04
    depth_slow: float = 0.05
    lateral_white: float = 0.002
    lateral_slow: float = 0.01
    swap_rate: float = 0.15
    turn_rate: float = 0.05
    swap_frames: int = 3
    spike_frac: float = 0.005
    spike_rad: float = 0.5
    slow_time: float = 0.3

    def validate(self) -> VideoNoise:
        """Raise InputError naming the first out-of-range value."""
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"video noise {name} must be a finite number >= 0, got {value:g}")
        if not self.spike_frac <= 1:
            raise InputError(f"video noise spike_frac must be <= 1, got {self.spike_frac:g}")
        if self.swap_frames < 1 or int(self.swap_frames) != self.swap_frames:
            raise InputError(f"video noise swap_frames must be a whole number >= 1, got "
                             f"{self.swap_frames:g}")  # fmt: skip
        return self

    def with_overrides(self, overrides: dict[str, float]) -> VideoNoise:
        """A copy with some fields replaced (``--set name=value``); InputError for an unknown
        name."""
        known = set(vars(self))
        for name in overrides:
            if name not in known:
                raise InputError(f"unknown video noise parameter {name!r} (known: "
                                 f"{', '.join(sorted(known))})")  # fmt: skip
        values = {**vars(self), **{k: float(v) for k, v in overrides.items()}}
        return VideoNoise(**values).validate()


def slow_noise(rng: np.random.Generator, shape: tuple, std: float, frames: float) -> np.ndarray:
    """A smooth, slowly varying random signal along axis 0: white noise smoothed by a Gaussian
    kernel of std ``frames`` frames (cut at 3 std), scaled to a stationary std of ``std``.
    shape: (T, ...) -> (T, ...)"""
    T = shape[0]
    r = max(1, math.ceil(3 * frames))
    e = rng.normal(0.0, 1.0, size=(T + 2 * r, *shape[1:]))
    if std == 0 or T == 0:
        return np.zeros(shape)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / max(frames, 1e-6)) ** 2)
    k /= np.sqrt((k**2).sum())
    flat = e.reshape(T + 2 * r, -1)
    out = np.stack([np.convolve(flat[:, j], k, mode="valid") for j in range(flat.shape[1])], 1)
    return std * out.reshape(shape)


def _events(rng: np.random.Generator, T: int, rate: float, fps: float, longest: int):
    """Frames hit by events arriving at ``rate`` per second, each 1..``longest`` frames long.
    -> (T,) bool"""
    hit = np.zeros(T, dtype=bool)
    starts = np.flatnonzero(rng.random(T) < rate / fps)
    lengths = rng.integers(1, longest + 1, size=len(starts))
    for s, n in zip(starts, lengths, strict=True):
        hit[s : s + n] = True
    return hit


def add_video_noise(motion: Motion, noise: VideoNoise, rng: np.random.Generator | int) -> Motion:
    """A noisy copy of ``motion`` (z up) with the errors of a video pose estimator
    (:class:`VideoNoise`; the input is not modified). Each kind of noise draws from its own
    stream of ``rng``, so turning one off leaves the others' draws unchanged."""
    noise.validate()
    T, fps = motion.num_frames, motion.fps
    a = noise.slow_time * fps  # the slow parts' time scale in frames
    rng = np.random.default_rng(rng)  # a seed too; a Generator as it is
    pose_rng, root_rng, trans_rng, swap_rng, turn_rng, spike_rng = rng.spawn(6)

    pose = motion.pose_body + pose_rng.normal(0.0, noise.pose_white, motion.pose_body.shape)
    pose += slow_noise(pose_rng, motion.pose_body.shape, noise.pose_slow, a)
    swapped = _events(swap_rng, T, noise.swap_rate, fps, int(noise.swap_frames))
    left, right = list(_LEFT_LEG), list(_RIGHT_LEG)
    legs = pose[swapped][:, left + right] * _MIRROR
    pose[np.ix_(swapped, left)] = legs[:, len(left) :]
    pose[np.ix_(swapped, right)] = legs[:, : len(left)]
    hit = spike_rng.random(pose.shape[:-1]) < noise.spike_frac
    pose[hit] += spike_rng.normal(0.0, noise.spike_rad, size=(int(hit.sum()), 3))

    root_noise = root_rng.normal(0.0, noise.root_white, (T, 3))
    root_noise += slow_noise(root_rng, (T, 3), noise.root_slow, a)
    root = motion.root_orient.copy()
    if noise.root_white or noise.root_slow:
        root = _compose(root_noise, root)
    turned = _events(turn_rng, T, noise.turn_rate, fps, int(noise.swap_frames))
    root[turned] = _compose(np.array([0.0, 0.0, math.pi]), root[turned])

    heading = trans_rng.uniform(0.0, 2 * math.pi)
    depth = np.array([math.cos(heading), math.sin(heading), 0.0])
    side = np.array([-math.sin(heading), math.cos(heading), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    amount = trans_rng.normal(0.0, 1.0, (T, 3)) * [noise.depth_white, *[noise.lateral_white] * 2]
    amount += np.stack([
        slow_noise(trans_rng, (T,), noise.depth_slow, a),
        slow_noise(trans_rng, (T,), noise.lateral_slow, a),
        slow_noise(trans_rng, (T,), noise.lateral_slow, a),
    ], axis=1)  # fmt: skip
    trans = motion.trans + amount @ np.stack([depth, side, up])
    noisy = motion.with_body(root_orient=root, pose_body=pose, trans=trans)
    noisy.joint_mask = None if motion.joint_mask is None else motion.joint_mask.copy()
    return noisy


def _compose(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Axis-angles of R(left) R(right).  (..., 3), (..., 3) -> (..., 3)"""
    import torch

    from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat

    def m(x):
        return rotvec_to_rotmat(torch.as_tensor(np.asarray(x, dtype=np.float64)))

    return rotmat_to_rotvec(m(left) @ m(right)).numpy()


#: ``mdvae add-noise --preset NAME``
PRESETS = {"video": VideoNoise()}
