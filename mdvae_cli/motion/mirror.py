"""Left-right mirror images of body motion, and the average of two estimates of one motion.

A mirror image reflects the world through the vertical plane x = 0 and swaps the body's left
and right joints. For SMPL-family bodies (left-right symmetric at rest, the body's left-right
axis along its x) a joint's local rotation R becomes M R M with M = diag(-1, 1, 1): an
axis-angle (a, b, c) becomes (a, -b, -c). Mirroring twice gives back the same numbers.
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.geometry.rotations import rotvec_slerp
from mdvae_cli.motion.motion import Motion

#: each of the 22 body joints' mirror partner (pelvis, hips, spine, knees, ... wrists)
MIRROR_JOINTS = (0, 2, 1, 3, 5, 4, 6, 8, 7, 9, 11, 10, 12, 14, 13, 15, 17, 16, 19, 18, 21, 20)
_FLIP_ROTVEC = np.array([1.0, -1.0, -1.0])
_FLIP_POINT = np.array([-1.0, 1.0, 1.0])


def mirror_rotvecs(rotvecs: np.ndarray) -> np.ndarray:
    """Local rotations of the mirrored body.  (..., 22, 3) axis-angles, joints in SMPL order
    -> (..., 22, 3): partners swapped, each reflected (a, b, c) -> (a, -b, -c)."""
    return rotvecs[..., MIRROR_JOINTS, :] * _FLIP_ROTVEC


def mirror_body(motion: Motion, pelvis_rest: np.ndarray) -> Motion:
    """The motion's left-right mirror image (body joints only; hands and the rest of
    ``pose_extra`` are kept as they are).

    pelvis_rest: (3,) the rest pelvis joint of the motion's shape (the root rotates about it,
    so the translation mirrors as ``M (trans + pelvis) - pelvis``).
    """
    T = motion.num_frames
    full = motion.joint_rotations
    flipped = mirror_rotvecs(full)
    mask = None if motion.joint_mask is None else motion.joint_mask[:, MIRROR_JOINTS]
    out = motion.with_body(
        root_orient=flipped[:, 0],
        pose_body=flipped[:, 1:].reshape(T, -1, 3),
        trans=(motion.trans + pelvis_rest) * _FLIP_POINT - pelvis_rest,
    )
    out.joint_mask = mask
    return out


def mirror_motion(motion: Motion, body: BodyModel) -> Motion:
    """:func:`mirror_body` with the rest pelvis of ``motion``'s shape under ``body``."""
    betas = torch.as_tensor(motion.betas, dtype=torch.float32)[None]
    return mirror_body(motion, body.pelvis_rest(betas)[0].double().numpy())


def average_bodies(a: Motion, b: Motion) -> Motion:
    """``a`` with its body parameters replaced by the midpoint of ``a``'s and ``b``'s: rotations
    by slerp halfway, translations by their mean. Both must have the same frames."""
    if a.num_frames != b.num_frames:
        raise ValueError(f"cannot average {a.num_frames} frames with {b.num_frames}")
    t = torch.as_tensor
    half = lambda x, y: rotvec_slerp(t(x), t(y), 0.5).numpy()  # noqa: E731
    return a.with_body(
        root_orient=half(a.root_orient, b.root_orient),
        pose_body=half(a.pose_body, b.pose_body),
        trans=0.5 * (a.trans + b.trans),
    )
