"""Denoise motions with a fitted Denoiser: windows -> one forward pass -> blended motion.

Any length and rate: a motion is resampled to 30 Hz, cut into overlapping windows of
``window + 1`` frames (frame 0 is x0), each window canonicalised, denoised in one batched pass
(regression mode: posterior means), moved back to the world, blended across overlaps (slerp on
rotations, lerp on translation) and resampled back to the input's own frame times. Hands, extra
keys and the file layout are carried through untouched.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.filters import filter_motions, savgol_smooth
from mdvae_cli.fit.closed_form import add_offset
from mdvae_cli.fit.data import MODEL_FPS, chunk_states, motion_to_params
from mdvae_cli.fit.refine import RefineConfig, refine_latents
from mdvae_cli.geometry.rotations import rotvec_slerp
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, observe
from mdvae_cli.model.small_batch import SmallBatchRegressor, small_batch_regressor
from mdvae_cli.motion.mirror import average_bodies, mirror_motion
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import (
    interp_linear,
    interp_rotvec,
    resample_motion,
    resample_times,
)
from mdvae_cli.motion.state import BodyParams, state_to_params
from mdvae_cli.motion.windows import CanonicalFrame, uncanonicalize, window_starts


@dataclass
class WindowGroup:
    """Windows of one length, ready for the networks.

    yn: (N, L, 138) normalised noisy states; y3d: (N, L, 65, 3); betas: (N, S);
    frame: the canonical frames; pelvis: (N, 3); owners: (motion index, start) per window;
    weight: (N, L, 65) observation weights (joint mask), or None; obs: (N, L, 138) the raw
    noisy states (state units, canonical frame; what refinement scores), or None.
    """

    yn: torch.Tensor
    y3d: torch.Tensor
    betas: torch.Tensor
    frame: CanonicalFrame
    pelvis: torch.Tensor
    owners: list[tuple[int, int]] = field(default_factory=list)
    weight: torch.Tensor | None = None
    obs: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.yn.shape[0])

    @property
    def moves(self) -> bool:
        """False for one-frame windows (x0 alone): nothing to fit or refine."""
        return self.yn.shape[1] > 1

    def batch(self, idx: torch.Tensor, with_y3d: bool = True) -> WindowGroup:
        w = None if self.weight is None else self.weight[idx]
        obs = None if self.obs is None else self.obs[idx]
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
        )


def make_windows(
    motions: list[Motion],
    denoiser: Denoiser,
    body: BodyModel,
    window: int = 60,
    stride: int = 45,
    observations: bool = True,
    points: bool = True,
) -> list[WindowGroup]:
    """Cut motions already at 30 Hz into windows of ``window + 1`` frames (shorter motions
    give one window of their own length), grouped by length.

    ``observations=False`` skips the observations (regression mode does not need them: the
    group then holds an empty y3d and no raw states); ``points=False`` keeps the raw states
    but skips the 3D points (refinement scores the states only)."""
    L = window + 1
    by_len: dict[int, list] = {}
    inputs = smooth_inputs(motions, denoiser.cfg)
    for mi, motion in enumerate(motions):
        p = motion_to_params(motion)
        p_in = p if inputs[mi] is motion else motion_to_params(inputs[mi])
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
        with torch.no_grad():
            states, frame = chunk_states(
                params, betas, body, velocity_window=denoiser.cfg.velocity_window
            )
            y3d, raw_states = states.new_zeros(0), None
            if observations:
                raw_states = states
                if denoiser.cfg.input_window > 1:  # the raw motion, in the same frames
                    raw = BodyParams(*(torch.stack([it[7][k] for it in items]) for k in range(3)))
                    raw_states = chunk_states(raw, betas, body, frame=frame)[0]
                if points:
                    y3d = observe(body, raw_states, betas)
        weight = None
        if any(it[6] is not None for it in items):
            masks = [
                it[6] if it[6] is not None else torch.ones(len(it[2]), 22, dtype=torch.bool)
                for it in items
            ]
            joints = torch.stack(masks).float()
            weight = torch.cat([joints, torch.ones(*joints.shape[:2], 43)], dim=-1)
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


MIN_FRAMES = 6  # at 30 Hz (0.17 s); shorter motions come out worse than they went in


def check_length(motion: Motion) -> None:
    """Raise InputError when a motion is too short to denoise: under ``MIN_FRAMES`` frames at
    30 Hz the networks have too little context, and on 24 val clips the output was further
    from the clean motion than the noisy input at every noise level (docs/model.md)."""
    n = len(resample_times(motion.num_frames, motion.fps, MODEL_FPS))
    if n < MIN_FRAMES:
        seconds = (motion.num_frames - 1) / motion.fps
        raise InputError(
            f"too short to denoise: {seconds:.3g} s ({n} frame(s) at {MODEL_FPS:g} Hz); "
            f"the denoiser needs at least {MIN_FRAMES} frames at {MODEL_FPS:g} Hz "
            f"({(MIN_FRAMES - 1) / MODEL_FPS:.2g} s)"
        )


SMALL_BATCH = 8  # windows; below this, per-operation overhead dominates the networks' cost


@contextmanager
def threads_for(num_windows: int, small: int = SMALL_BATCH):
    """Run a handful of windows on one CPU thread: for tiny batches, thread synchronisation
    costs more than it saves (a 2-second clip: 21 ms on one thread, 28 ms on two)."""
    before = torch.get_num_threads()
    if num_windows <= small and before > 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@torch.no_grad()
def predict_windows(denoiser: Denoiser, group: WindowGroup, batch_size: int = 1024) -> BodyParams:
    """Regression mode on a group: posterior means, back in world coordinates. A handful of
    windows go through the numpy path (same numbers, a third of the time).

    -> BodyParams with (N, L, ...) tensors
    """
    regress = regressor(denoiser, len(group))
    outs = []
    with threads_for(len(group)):
        for i in range(0, len(group), batch_size):
            idx = torch.arange(i, min(i + batch_size, len(group)))
            g = group.batch(idx, with_y3d=False)
            x_hat = regress(g.yn)
            outs.append(uncanonicalize(state_to_params(x_hat), g.frame, g.pelvis))
    return BodyParams(
        *(torch.cat([getattr(o, k) for o in outs]) for k in ("root_orient", "pose_body", "trans"))
    )


def regressor(denoiser: Denoiser, num_windows: int) -> Callable[[torch.Tensor], torch.Tensor]:
    """Regression mode's forward pass for a batch of ``num_windows``: normalised inputs
    (N, T+1, 138) -> denormalised posterior-mean states (N, T+1, 138). A handful of windows go
    through the numpy path (same numbers, a third of the time)."""
    if denoiser.training:
        denoiser.eval()
    if num_windows <= SMALL_BATCH and SmallBatchRegressor.supports(denoiser):
        return lambda yn: torch.from_numpy(small_batch_regressor(denoiser)(yn.numpy()))
    return lambda yn: denoiser.infer(yn, with_prior=False)["x_hat"]


def refine_windows(
    denoiser: Denoiser,
    group: WindowGroup,
    cfg: RefineConfig,
    progress: Callable[[dict], None] | None = None,
) -> BodyParams:
    """Latent refinement on a group (see ``fit.refine``), back in world coordinates.

    The group must hold its raw states (``make_windows(..., observations=True)``).
    ``progress`` counts steps over all of the group's batches. One-frame windows are predicted.
    -> BodyParams with (N, L, ...) tensors
    """
    if group.obs is None:
        raise ValueError("refinement needs the raw states: make_windows(observations=True)")
    starts = refine_batches(group, cfg)
    if not starts:  # one-frame windows: x0 alone, nothing to refine
        return predict_windows(denoiser, group)
    if denoiser.training:
        denoiser.eval()
    outs = []
    for b, i in enumerate(starts):
        idx = torch.arange(i, min(i + cfg.batch_windows, len(group)))
        g = group.batch(idx, with_y3d=False)
        joints = None if g.weight is None else g.weight[..., :22]
        if cfg.steps == 0:  # the offset alone on regression mode's states
            with torch.no_grad():
                x_hat = add_offset(regressor(denoiser, len(idx))(g.yn), g.obs, joints, cfg)
        else:
            tell = _staged(progress, "refine", b * cfg.steps, len(starts) * cfg.steps)
            x_hat = refine_latents(denoiser, g.yn, g.obs, joints, cfg, tell)
        outs.append(uncanonicalize(state_to_params(x_hat), g.frame, g.pelvis))
    return BodyParams(
        *(torch.cat([getattr(o, k) for o in outs]) for k in ("root_orient", "pose_body", "trans"))
    )


def refine_batches(group: WindowGroup, cfg: RefineConfig) -> range:
    """Where the group's refinement batches start (none for one-frame windows)."""
    return range(0, len(group) if group.moves else 0, cfg.batch_windows)


def blend_windows(num_frames: int, starts: list[int], windows: list[BodyParams]) -> BodyParams:
    """Stitch windows (each (L, ...)) into one (T, ...) sequence; overlaps cross-fade linearly
    (slerp for rotations) from the earlier window to the later one."""
    root = torch.zeros(num_frames, 3)
    pose = torch.zeros(num_frames, 21, 3)
    trans = torch.zeros(num_frames, 3)
    written = 0
    for s, w in sorted(zip(starts, windows, strict=True), key=lambda sw: sw[0]):
        L = w.trans.shape[0]
        ov = max(0, min(written - s, L))
        if ov:
            a = torch.arange(1, ov + 1, dtype=torch.float32) / (ov + 1)
            sl = slice(s, s + ov)
            root[sl] = rotvec_slerp(root[sl], w.root_orient[:ov], a[:, None].expand(ov, 1)[:, 0])
            pose[sl] = rotvec_slerp(pose[sl], w.pose_body[:ov], a[:, None].expand(ov, 21))
            trans[sl] = trans[sl] * (1 - a[:, None]) + w.trans[:ov] * a[:, None]
        root[s + ov : s + L] = w.root_orient[ov:]
        pose[s + ov : s + L] = w.pose_body[ov:]
        trans[s + ov : s + L] = w.trans[ov:]
        written = max(written, s + L)
    return BodyParams(root, pose, trans)


def to_input_rate(params30: BodyParams, source: Motion) -> BodyParams:
    """Sample a 30 Hz result at the source's own frame times (same frame count as the input)."""
    if abs(source.fps - MODEL_FPS) < 1e-9:
        return params30
    T30 = params30.trans.shape[0]
    src = np.clip(np.arange(source.num_frames) * (MODEL_FPS / source.fps), 0, T30 - 1)
    return BodyParams(
        torch.as_tensor(interp_rotvec(params30.root_orient.double().numpy(), src)),
        torch.as_tensor(interp_rotvec(params30.pose_body.double().numpy(), src)),
        torch.as_tensor(interp_linear(params30.trans.double().numpy(), src)),
    )


def assemble(
    motions: list[Motion],
    motions30: list[Motion],
    groups: list[WindowGroup],
    predictions: list[BodyParams],
) -> list[Motion]:
    """Blend every motion's windows and write the results into copies of the input motions."""
    per_motion: dict[int, list[tuple[int, BodyParams]]] = {}
    for g, pred in zip(groups, predictions, strict=True):
        for k, (mi, s) in enumerate(g.owners):
            one = BodyParams(pred.root_orient[k], pred.pose_body[k], pred.trans[k])
            per_motion.setdefault(mi, []).append((s, one))
    out = []
    for mi, (motion, m30) in enumerate(zip(motions, motions30, strict=True)):
        items = per_motion[mi]
        p30 = blend_windows(m30.num_frames, [s for s, _ in items], [w for _, w in items])
        p = to_input_rate(p30, motion)
        out.append(
            motion.with_body(
                root_orient=p.root_orient.double().numpy(),
                pose_body=p.pose_body.double().numpy(),
                trans=p.trans.double().numpy(),
            )
        )
    return out


def denoise_motions(
    motions: list[Motion],
    denoiser: Denoiser,
    body: BodyModel,
    window: int = 60,
    stride: int = 45,
    optimize_steps: int = 0,
    lr: float = 3e-4,
    batch_size: int = 64,
    seed: int = 0,
    progress: Callable[[dict], None] | None = None,
    refine: RefineConfig | None = None,
    mirror: bool = False,
) -> list[Motion]:
    """Denoise whole motions (any length and rate) in one batch.

    Regression mode (``optimize_steps=0``): one forward pass. Optimisation mode: first adapt
    the inference networks to these very motions for ``optimize_steps`` ELBO steps (this
    modifies ``denoiser``; pass a copy to keep the original), then predict. With ``refine``
    (``steps`` > 0), each window's latents are then refined on its own ELBO (``fit.refine``);
    with ``steps`` = 0 and ``offset_std`` > 0, the latents stay the encoder's and only the slow
    offset is fitted (closed form, no gradients).
    With ``mirror``, each motion's left-right mirror image is denoised in the same batch (and,
    in optimisation mode, adapted to as well) and the result is the midpoint of the two
    estimates, mirrored back: the learned prior is not exactly mirror-symmetric, so the two
    differ, and their average is a prior made symmetric. Twice the work.
    ``progress`` receives {"stage": "optimize" | "refine", "step", "steps", "loss"}.
    """
    for i, m in enumerate(motions):
        try:
            check_length(m)
        except InputError as exc:
            raise InputError(f"motion {i}: {exc}") from None
    if mirror:
        flipped = [mirror_motion(m, body) for m in motions]
        both = denoise_motions(
            [*motions, *flipped], denoiser, body, window, stride, optimize_steps, lr,
            batch_size, seed, progress, refine,
        )  # fmt: skip
        n = len(motions)
        return [
            average_bodies(a, mirror_motion(b, body))
            for a, b in zip(both[:n], both[n:], strict=True)
        ]
    refining = refine is not None and refine.active
    motions30 = [resample_motion(m, MODEL_FPS) for m in motions]
    num_windows = sum(len(motion_window_starts(m, window, stride)) for m in motions30)
    observed = optimize_steps > 0 or refining
    with threads_for(num_windows) if optimize_steps == 0 else nullcontext():
        groups = make_windows(
            motions30, denoiser, body, window, stride, observed, points=optimize_steps > 0
        )
        if optimize_steps > 0:
            from mdvae_cli.fit.fit_dataset import fit_denoiser

            tell = _staged(progress, "optimize", 0, optimize_steps)
            draws = torch.Generator().manual_seed(seed)  # reproducible whatever ran before
            fit_denoiser(
                denoiser, groups, body, optimize_steps, lr, batch_size, seed, tell,
                sample_generator=draws,
            )  # fmt: skip
        if not refining:
            preds = [predict_windows(denoiser, g) for g in groups]
            return assemble(motions, motions30, groups, preds)
        steps = [len(refine_batches(g, refine)) * refine.steps for g in groups]
        preds = [
            refine_windows(denoiser, g, refine, _staged(progress, "refine", done, sum(steps)))
            for g, done in zip(groups, itertools.accumulate([0, *steps]), strict=False)
        ]
        return assemble(motions, motions30, groups, preds)


def _staged(progress, stage: str, offset: int, total: int):
    """A progress callback that labels its stage and counts steps over several runs."""
    if progress is None:
        return None

    def tell(info: dict) -> None:
        progress({**info, "stage": stage, "step": offset + info["step"], "steps": total})

    return tell
