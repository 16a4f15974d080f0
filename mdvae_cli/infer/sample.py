"""Generate motion from the prior alone, continuing a real motion's first frame."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.chunks import MODEL_FPS, chunk_states, motion_to_params
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.model.state import BodyParams, state_to_params
from mdvae_cli.model.windows import uncanonicalize
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import resample_motion

FOOT_JOINTS = (7, 8, 10, 11)  # ankles and feet of the 22 body joints
#: default joint speed limit (m/s): every joint is slower in 99.9 % of the CMU train frames
SPEED_LIMIT = 10.0
#: default number of particles of the conditioned sampler
PARTICLES = 64


def motion_floor(body: BodyModel, motion: Motion) -> float:
    """The lowest height (m, z up) any foot joint of ``motion`` reaches: where its floor is."""
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    with torch.no_grad():
        out = body(
            t(motion.root_orient), t(motion.pose_body), t(motion.trans), t(motion.betas)[None]
        )
    return float(out.joints[:, FOOT_JOINTS, 2].min())


def plausibility_log_weight(
    body: BodyModel,
    x: torch.Tensor,
    prev: torch.Tensor,
    betas: torch.Tensor,
    floor: float | None,
    tolerance: float = 0.01,
    speed_limit: float | None = None,
    speed_tolerance: float = 2.0,
    fps: float = MODEL_FPS,
) -> torch.Tensor:
    """How physically plausible a frame is, as a log-weight: -d^2 / (2 tolerance^2), d (m) how
    far the lowest foot joint sinks below ``floor``, plus -e^2 / (2 speed_tolerance^2), e (m/s)
    how far the fastest joint exceeds ``speed_limit`` since the frame before (each 0 when
    within bounds; None = not checked).

    x, prev: (B, M, 138) canonical states of this frame and the one before (height is the
    world's: canonical frames only turn about and move along the floor); betas: (B, S)
    -> (B, M)
    """
    B, M = x.shape[:2]
    frames = [x] if speed_limit is None else [x, prev]  # posed together: one skinning call
    p = state_to_params(torch.cat(frames).flatten(0, 1))
    rows = betas.repeat_interleave(M, dim=0).repeat(len(frames), 1)
    joints = body(p.root_orient, p.pose_body, p.trans, rows).joints.unflatten(0, (-1, B * M))
    out = x.new_zeros(B, M)
    if floor is not None:
        lowest = joints[0, :, FOOT_JOINTS, 2].amin(dim=1).unflatten(0, (B, M))
        out = out - 0.5 * (torch.clamp(floor - lowest, min=0.0) / tolerance) ** 2
    if speed_limit is not None:
        speed = (joints[0] - joints[1]).norm(dim=-1).amax(dim=1).unflatten(0, (B, M)) * fps
        out = out - 0.5 * (torch.clamp(speed - speed_limit, min=0.0) / speed_tolerance) ** 2
    return out


@torch.no_grad()
def sample_motion(
    prior: PriorModel,
    body: BodyModel,
    start: Motion,
    num_frames: int,
    seed: int = 0,
    window: int = 60,
    temperature: float = 1.0,
    floor: float | None = None,
    particles: int = PARTICLES,
    floor_tolerance: float = 0.01,
    speed_limit: float | None = None,
    progress: Callable[[dict], None] | None = None,
) -> Motion:
    """``num_frames`` frames at 30 Hz sampled from p(x | x0), x0 = the start's first frame.

    Longer samples chain windows: each window's last state becomes the next window's x0
    (re-canonicalised), so the networks always run at the length they were trained on.
    The result keeps the start's shape, gender and file layout (hands at rest).

    floor: a height (m, the file's up axis z) the foot joints should stay above, e.g.
    :func:`motion_floor` of the start; speed_limit (m/s): the fastest a joint should move.
    With either, the prior is conditioned on them by a particle filter over ``particles``
    prior samples, each frame weighted by :func:`plausibility_log_weight` (``floor_tolerance``:
    how far below the floor a foot may dip before its weight falls by e^-0.5); with neither
    (None), plain prior samples. ``progress`` gets {"step", "steps", "frames"} after each
    window (steps counted in windows, frames made so far); it does not change the sample.
    """
    gen = torch.Generator().manual_seed(seed)
    m30 = resample_motion(start, MODEL_FPS)
    p = motion_to_params(m30)
    betas = body.fit_betas(torch.as_tensor(start.betas, dtype=torch.float32)[None])
    pelvis = body.pelvis_rest(betas)
    # x0 is the first frame; its velocity comes from the first two frames
    first = BodyParams(p.root_orient[None, :2], p.pose_body[None, :2], p.trans[None, :2])
    weigh = None  # the plausibility condition on decoded states: 2 x (B, M, 138) -> (B, M)
    if floor is not None or speed_limit is not None:
        weigh = lambda x, prev: plausibility_log_weight(  # noqa: E731
            body, x, prev, betas, floor, floor_tolerance, speed_limit
        )
    pieces: list[BodyParams] = []
    made = 0
    while made < num_frames:
        states, frame = chunk_states(first, betas, body)
        n = min(window, num_frames - made)
        x = prior.sample(
            states[:, 0], n, generator=gen, temperature=temperature,
            particles=particles, log_weight=weigh,
        )  # fmt: skip
        world = uncanonicalize(state_to_params(x), frame, pelvis)
        pieces.append(world)
        made += n
        if progress is not None:
            progress({"step": len(pieces), "steps": -(-num_frames // window), "frames": made})
        prev = pieces[-1]
        last2 = slice(max(0, n - 2), n)
        first = BodyParams(
            prev.root_orient[:, last2], prev.pose_body[:, last2], prev.trans[:, last2]
        )
        if first.trans.shape[1] < 2:  # a one-frame piece: repeat it
            first = BodyParams(
                *(
                    t.repeat(1, 2, *([1] * (t.ndim - 2)))
                    for t in (first.root_orient, first.pose_body, first.trans)
                )
            )
    cat = lambda k: torch.cat([getattr(q, k)[0] for q in pieces]).double().numpy()  # noqa: E731
    T = num_frames
    per_frame = [k for k, v in start.extras.items() if v.ndim and v.shape[0] == start.num_frames]
    extras = {k: v for k, v in start.extras.items() if k not in per_frame}
    notes = [f"per-frame keys of the start file are not carried into the sample: "
             f"{', '.join(per_frame)}"] if per_frame else []  # fmt: skip
    return Motion(
        root_orient=cat("root_orient"),
        pose_body=cat("pose_body"),
        trans=cat("trans"),
        betas=start.betas.copy(),
        fps=MODEL_FPS,
        pose_extra=np.zeros((T, start.pose_extra.shape[1])),
        gender=start.gender,
        extras=extras,
        layout=dict(start.layout),
        notes=notes,
    )
