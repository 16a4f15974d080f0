"""Generate motion from the prior alone, continuing a real motion's first frame."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.fit.data import MODEL_FPS, chunk_states, motion_to_params
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.motion.state import BodyParams, state_to_params
from mdvae_cli.motion.windows import uncanonicalize


@torch.no_grad()
def sample_motion(
    prior: PriorModel,
    body: BodyModel,
    start: Motion,
    num_frames: int,
    seed: int = 0,
    window: int = 60,
    temperature: float = 1.0,
) -> Motion:
    """``num_frames`` frames at 30 Hz sampled from p(x | x0), x0 = the start's first frame.

    Longer samples chain windows: each window's last state becomes the next window's x0
    (re-canonicalised), so the networks always run at the length they were trained on.
    The result keeps the start's shape, gender and file layout (hands at rest).
    """
    gen = torch.Generator().manual_seed(seed)
    m30 = resample_motion(start, MODEL_FPS)
    p = motion_to_params(m30)
    betas = body.fit_betas(torch.as_tensor(start.betas, dtype=torch.float32)[None])
    pelvis = body.pelvis_rest(betas)
    # x0 is the first frame; its velocity comes from the first two frames
    first = BodyParams(p.root_orient[None, :2], p.pose_body[None, :2], p.trans[None, :2])
    pieces: list[BodyParams] = []
    made = 0
    while made < num_frames:
        states, frame = chunk_states(first, betas, body)
        n = min(window, num_frames - made)
        x = prior.sample(states[:, 0], n, generator=gen, temperature=temperature)
        world = uncanonicalize(state_to_params(x), frame, pelvis)
        pieces.append(world)
        made += n
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
    extras = {
        k: v for k, v in start.extras.items() if not (v.ndim and v.shape[0] == start.num_frames)
    }
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
    )
