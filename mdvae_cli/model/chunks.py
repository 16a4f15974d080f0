"""Motion -> canonical state chunks at the model rate: what both training and denoising cut
windows into before the networks see them."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.state import BodyParams, params_to_state
from mdvae_cli.model.windows import CanonicalFrame, canonical_frame, canonicalize
from mdvae_cli.motion.motion import Motion

MODEL_FPS = 30.0


def chunk_states(
    params: BodyParams,
    betas: torch.Tensor,
    body: BodyModel,
    fps: float = MODEL_FPS,
    velocity_window: int = 1,
    frame: CanonicalFrame | None = None,
) -> tuple[torch.Tensor, CanonicalFrame]:
    """Canonicalise chunks (with their own frame, or ``frame``) and build their states.

    params: (B, T+1, ...) chunks whose frame 0 is x0; betas: (B, S) -> states (B, T+1, 138)
    """
    canon, frame = canonicalize(params, body.pelvis_rest(betas), frame)
    return params_to_state(canon, fps, velocity_window), frame


def chunk_state_pair(
    inputs: BodyParams,
    raw: BodyParams,
    betas: torch.Tensor,
    body: BodyModel,
    fps: float = MODEL_FPS,
    velocity_window: int = 1,
) -> tuple[torch.Tensor, torch.Tensor, CanonicalFrame]:
    """Two versions of the same chunks — what the networks read (``inputs``) and the raw
    motion — canonicalised together in the frames of ``inputs`` (one pass over twice the
    chunks costs less than two passes). The raw states take plain differences.

    inputs, raw: (B, T+1, ...) chunks; betas: (B, S) -> (input states, raw states), each
    (B, T+1, 138), and the frames
    """
    pelvis = body.pelvis_rest(betas)
    frame = canonical_frame(inputs, pelvis)
    both = BodyParams(
        *(torch.cat([a, b]) for a, b in zip(_fields(inputs), _fields(raw), strict=True))
    )
    twice = CanonicalFrame(torch.cat([frame.yaw] * 2), torch.cat([frame.origin] * 2))
    canon, _ = canonicalize(both, torch.cat([pelvis, pelvis]), twice)
    B = len(betas)
    half = lambda sl: BodyParams(*(a[sl] for a in _fields(canon)))  # noqa: E731
    states = params_to_state(half(slice(0, B)), fps, velocity_window)
    return states, params_to_state(half(slice(B, None)), fps), frame


def _fields(p: BodyParams) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return p.root_orient, p.pose_body, p.trans


def motion_to_params(motion: Motion, dtype=torch.float32) -> BodyParams:
    """(T, ...) numpy body parameters of a Motion as torch."""
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    return BodyParams(t(motion.root_orient), t(motion.pose_body), t(motion.trans))
