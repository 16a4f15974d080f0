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
    rng: np.random.Generator,
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
