"""Motions at 30 Hz cut into the windows the inference networks read, grouped by length:
canonical states, what the networks read (through the config's input filter), and the
observations the likelihoods score. Used by regression mode, refinement and fit-dataset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import filter_motions, savgol_smooth
from mdvae_cli.model.chunks import chunk_state_pair, chunk_states, motion_to_params
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, observe
from mdvae_cli.model.state import BodyParams
from mdvae_cli.model.windows import CanonicalFrame, window_starts
from mdvae_cli.motion.motion import Motion


@dataclass
class WindowGroup:
    """Windows of one length, ready for the networks.

    yn: (N, L, 138) normalised noisy states; y3d: (N, L, 65, 3); betas: (N, S);
    frame: the canonical frames; pelvis: (N, 3); owners: (motion index, start) per window;
    weight: (N, L, 65) observation weights (joint mask), or None; obs: (N, L, 138) the raw
    noisy states (state units, canonical frame; what refinement scores), or None; seen:
    (N, L, 22) where the networks read a joint as there (1) or as a hole (0), when that is
    not ``weight`` (training copies whose hidden frames the likelihood still scores), or None.
    """

    yn: torch.Tensor
    y3d: torch.Tensor
    betas: torch.Tensor
    frame: CanonicalFrame
    pelvis: torch.Tensor
    owners: list[tuple[int, int]] = field(default_factory=list)
    weight: torch.Tensor | None = None
    obs: torch.Tensor | None = None
    seen: torch.Tensor | None = None

    @property
    def read_weight(self) -> torch.Tensor | None:
        """What the networks read as there or missing (``Denoiser.read_holes``)."""
        return self.weight if self.seen is None else self.seen

    def __len__(self) -> int:
        return int(self.yn.shape[0])

    @property
    def moves(self) -> bool:
        """False for one-frame windows (x0 alone): nothing to fit or refine."""
        return self.yn.shape[1] > 1

    def batch(self, idx: torch.Tensor, with_y3d: bool = True) -> WindowGroup:
        w = None if self.weight is None else self.weight[idx]
        obs = None if self.obs is None else self.obs[idx]
        seen = None if self.seen is None else self.seen[idx]
        frame = CanonicalFrame(self.frame.yaw[idx], self.frame.origin[idx])
        return WindowGroup(
            self.yn[idx],
            self.y3d[idx] if with_y3d else self.y3d,
            self.betas[idx],
            frame,
            self.pelvis[idx],
            [self.owners[i] for i in idx.tolist()],
            w,
            obs,
            seen,
        )


def make_windows(
    motions: list[Motion],
    denoiser: Denoiser,
    body: BodyModel,
    window: int = 60,
    stride: int = 45,
    observations: bool = True,
    points: bool = True,
    scored: list[Motion] | None = None,
) -> list[WindowGroup]:
    """Cut motions already at 30 Hz into windows of ``window + 1`` frames (shorter motions
    give one window of their own length), grouped by length.

    ``observations=False`` skips the observations (regression mode does not need them: the
    group then holds an empty y3d and no raw states); ``points=False`` keeps the raw states
    but skips the 3D points (refinement scores the states only). ``scored``: motions of the
    same lengths whose values the observations are, everywhere (the networks read
    ``motions``, whose holes become the groups' ``seen``; the likelihoods score ``scored``,
    the frames hidden from the networks included)."""
    L = window + 1
    by_len: dict[int, list] = {}
    inputs = smooth_inputs(motions, denoiser.cfg)
    for mi, motion in enumerate(motions):
        p = motion_to_params(motion if scored is None else scored[mi])
        p_in = motion_to_params(inputs[mi]) if inputs[mi] is not motion or scored else p
        betas = body.fit_betas(torch.as_tensor(motion.betas, dtype=torch.float32)[None])[0]
        length = min(L, motion.num_frames)
        for s in motion_window_starts(motion, window, stride):
            sl = slice(s, s + length)
            mask = None if motion.joint_mask is None else torch.as_tensor(motion.joint_mask[sl])
            raw = (p.root_orient[sl], p.pose_body[sl], p.trans[sl])
            by_len.setdefault(length, []).append(
                (mi, s, p_in.root_orient[sl], p_in.pose_body[sl], p_in.trans[sl], betas, mask, raw)
            )
    groups = []
    norm = denoiser.prior.normalizer
    for _, items in sorted(by_len.items()):
        stack = lambda k, items=items: torch.stack([it[k] for it in items])  # noqa: E731
        params = BodyParams(stack(2), stack(3), stack(4))
        betas = stack(5)
        vw = denoiser.cfg.velocity_window
        with torch.no_grad():
            if observations and (denoiser.cfg.input_window > 1 or scored):  # the raw too
                raw = BodyParams(*(torch.stack([it[7][k] for it in items]) for k in range(3)))
                states, raw_states, frame = chunk_state_pair(
                    params, raw, betas, body, velocity_window=vw
                )
            else:
                states, frame = chunk_states(params, betas, body, velocity_window=vw)
                raw_states = states if observations else None
            y3d = states.new_zeros(0)
            if observations:
                if points:
                    y3d = observe(body, raw_states, betas)
        weight = seen = None
        if any(it[6] is not None for it in items):
            masks = [
                it[6] if it[6] is not None else torch.ones(len(it[2]), 22, dtype=torch.bool)
                for it in items
            ]
            joints = torch.stack(masks).float()
            if scored is None:
                weight = torch.cat([joints, torch.ones(*joints.shape[:2], 43)], dim=-1)
            else:
                seen = joints
        groups.append(
            WindowGroup(
                norm.normalize(states),
                y3d,
                betas,
                frame,
                body.pelvis_rest(betas),
                [(it[0], it[1]) for it in items],
                weight,
                raw_states,
                seen,
            )
        )
    return groups


def motion_window_starts(motion: Motion, window: int, stride: int) -> list[int]:
    """Where a 30 Hz motion's windows of ``window + 1`` frames start (one window of its own
    length when it is shorter)."""
    T = motion.num_frames
    return window_starts(T, min(window + 1, T), stride)


def smooth_inputs(motions: list[Motion], cfg: DenoiserConfig) -> list[Motion]:
    """What the inference networks read: the motions through the config's input filter (the
    window is shortened to fit a short motion; 0 or 1 frame = the motion itself). Motions of
    one length are filtered together."""
    out = list(motions)
    by_window: dict[int, list[int]] = {}
    for i, m in enumerate(motions):
        window = min(cfg.input_window, m.num_frames - (1 - m.num_frames % 2))
        if window > 1 and window > cfg.input_order:
            by_window.setdefault(window, []).append(i)
    for window, idx in by_window.items():
        smooth = lambda x, w=window: savgol_smooth(x, w, cfg.input_order)  # noqa: E731
        for i, m in zip(idx, filter_motions([motions[i] for i in idx], smooth), strict=True):
            out[i] = m
    return out
