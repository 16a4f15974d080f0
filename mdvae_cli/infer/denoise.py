"""Denoise motions with a fitted Denoiser: windows -> one forward pass -> blended motion.

Any length and rate: a motion is resampled to 30 Hz, cut into overlapping windows of
``window + 1`` frames (frame 0 is x0), each window canonicalised, denoised in one batched pass
(regression mode: posterior means), moved back to the world, blended across overlaps (slerp on
rotations, lerp on translation) and resampled back to the input's own frame times. Hands, extra
keys and the file layout are carried through untouched.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Sequence
from contextlib import nullcontext

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.infer.closed_form import add_offset
from mdvae_cli.infer.feet import FootLockConfig, lock_motions
from mdvae_cli.infer.fill import fill_holes, has_holes, observed_pieces
from mdvae_cli.infer.fill_choices import DEFAULT_FILL
from mdvae_cli.infer.guard import fallback_stretches, guard, guard_note
from mdvae_cli.infer.native_rate import to_model_rate
from mdvae_cli.infer.noise_blend import BlendReport, blend_motion
from mdvae_cli.infer.pieces import denoise_pieces
from mdvae_cli.infer.progress import (
    CORE_PHASES,
    more_phases,
    phase,
    progress_of_runs,
    staged,
    stoppable,
)
from mdvae_cli.infer.refine import refine_latents, window_batches
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.infer.stitch import assemble
from mdvae_cli.infer.window_groups import WindowGroup, make_windows, motion_window_starts
from mdvae_cli.model.chunks import MODEL_FPS
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.model.small_batch import SmallBatchRegressor, small_batch_regressor, threads_for
from mdvae_cli.model.state import BodyParams, state_to_params
from mdvae_cli.model.windows import uncanonicalize
from mdvae_cli.motion.mirror import average_bodies, mirror_motion
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import resample_times
from mdvae_cli.workers import map_in_order, worker_count

MIN_FRAMES = 6  # at 30 Hz (0.17 s); shorter motions come out worse than they went in


def check_length(motion: Motion) -> None:
    """Raise InputError when a motion is too short to denoise: under ``MIN_FRAMES`` frames at
    30 Hz the networks have too little context, and on 24 val clips the output was further
    from the clean motion than the noisy input at every noise level (docs/model.md)."""
    n = len(resample_times(motion.num_frames, motion.fps, MODEL_FPS))
    if n < MIN_FRAMES:
        seconds = (motion.num_frames - 1) / motion.fps
        raise InputError(
            f"too short to denoise: {motion.num_frames} frame(s) at {motion.fps:g} Hz "
            f"({seconds:.3g} s); the denoiser needs {(MIN_FRAMES - 1) / MODEL_FPS:.2g} s or "
            f"more ({MIN_FRAMES} frames at {MODEL_FPS:g} Hz)"
        )


def check_finite(motion: Motion) -> None:
    """Raise InputError when a result holds nan or inf (a diverged optimisation or
    refinement), so that it is never written."""
    for name in ("root_orient", "pose_body", "trans"):
        if not np.isfinite(getattr(motion, name)).all():
            raise InputError(
                f"the result's {name} is not finite (the optimisation diverged); nothing "
                "written: try a smaller --lr or --refine-lr"
            )


SMALL_BATCH = 8  # windows; below this, per-operation overhead dominates the networks' cost


@torch.no_grad()
def predict_windows(
    denoiser: Denoiser,
    group: WindowGroup,
    batch_size: int = 1024,
    fallbacks: list[tuple[int, int]] | None = None,
) -> BodyParams:
    """Regression mode on a group: posterior means, back in world coordinates. A handful of
    windows go through the numpy path (same numbers, a third of the time). With
    ``fallbacks`` (a list) and the group's raw states, windows past the guard
    (``infer.guard``) fall back to the smoothed input and their owners are appended to it.

    -> BodyParams with (N, L, ...) tensors
    """
    regress = regressor(denoiser, len(group))
    outs = []
    with threads_for(len(group), SMALL_BATCH):
        for i in range(0, len(group), batch_size):
            idx = torch.arange(i, min(i + batch_size, len(group)))
            g = group.batch(idx, with_y3d=False)
            x_hat = _guarded(regress(denoiser.read_holes(g.yn, g.read_weight)), g, fallbacks)
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


def _guarded(
    x_hat: torch.Tensor, g: WindowGroup, fallbacks: list[tuple[int, int]] | None
) -> torch.Tensor:
    """``x_hat`` (N, T, 138) with the windows past the guard replaced (their owners appended
    to ``fallbacks``); unchanged when ``fallbacks`` is None or the raw states are missing."""
    if fallbacks is None or g.obs is None or not g.moves:
        return x_hat
    x_hat, bad = guard(x_hat, g.obs)
    fallbacks += [g.owners[i] for i in torch.nonzero(bad).flatten().tolist()]
    return x_hat


def refine_windows(
    denoiser: Denoiser,
    group: WindowGroup,
    cfg: RefineConfig,
    progress: Callable[[dict], None] | None = None,
    fallbacks: list[tuple[int, int]] | None = None,
    workers: int = 1,
) -> BodyParams:
    """Latent refinement on a group (see ``infer.refine``), back in world coordinates.

    The group must hold its raw states (``make_windows(..., observations=True)``).
    ``progress`` counts steps over all of the group's batches. One-frame windows are predicted.
    With refinement steps, the batches go ``workers`` at a time side by side, torch one
    thread in each (:func:`refine_batches`; each window's steps depend on that window alone,
    so the numbers are the same but for the products' rounding).
    -> BodyParams with (N, L, ...) tensors
    """
    if group.obs is None:
        raise ValueError("refinement needs the raw states: make_windows(observations=True)")
    workers = workers if cfg.steps > 0 else 1
    batches = refine_batches(group, cfg, workers)
    if not batches:  # one-frame windows: x0 alone, nothing to refine
        return predict_windows(denoiser, group, fallbacks=fallbacks)
    if denoiser.training:
        denoiser.eval()
    n = len(batches)
    tells = progress_of_runs(staged(progress, "refine", 0, n * cfg.steps), 0, n, n)
    stop = threading.Event()  # set when the batches side by side are left (Ctrl-C)

    def refine_batch(b: int) -> tuple[BodyParams, list[tuple[int, int]]]:
        g = group.batch(batches[b], with_y3d=False)
        joints = None if g.weight is None else g.weight[..., :22]
        with torch.no_grad():
            yn = denoiser.read_holes(g.yn, g.read_weight)
        if cfg.steps == 0:  # the offset alone on regression mode's states
            with torch.no_grad():
                x_hat = add_offset(regressor(denoiser, len(g))(yn), g.obs, joints, cfg)
        else:
            x_hat = refine_latents(denoiser, yn, g.obs, joints, cfg, stoppable(tells[b], stop))
        bad: list[tuple[int, int]] = []
        x_hat = _guarded(x_hat.detach(), g, None if fallbacks is None else bad)
        return uncanonicalize(state_to_params(x_hat), g.frame, g.pelvis), bad

    outs = []
    for params, bad in map_in_order(refine_batch, range(n), workers, stop):
        outs.append(params)
        if fallbacks is not None:
            fallbacks += bad
    return BodyParams(
        *(torch.cat([getattr(o, k) for o in outs]) for k in ("root_orient", "pose_body", "trans"))
    )


def refine_batches(group: WindowGroup, cfg: RefineConfig, workers: int = 1) -> list[torch.Tensor]:
    """The group's refinement batches (``infer.refine.window_batches``; none for one-frame
    windows)."""
    return window_batches(len(group) if group.moves else 0, cfg, workers)


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
    guard: bool = False,
    on_fallback: Callable[[int, float, float], None] | None = None,
    loops: Sequence[bool] | None = None,
    feet: FootLockConfig | None = None,
    blend: bool = False,
    on_blend: Callable[[int, BlendReport], None] | None = None,
    blend_fast: bool = True,
    fill: str | None = DEFAULT_FILL,
    split: bool = True,
) -> list[Motion]:
    """Denoise whole motions (any length and rate) in one batch.

    Regression mode (``optimize_steps=0``): one forward pass. Optimisation mode: first adapt
    the inference networks to these very motions for ``optimize_steps`` ELBO steps (this
    modifies ``denoiser``; pass a copy to keep the original), then predict. With ``refine``
    (``steps`` > 0), each window's latents are then refined on its own ELBO (``infer.refine``);
    with ``steps`` = 0 and ``offset_std`` > 0, the latents stay the encoder's and only the slow
    offset is fitted (closed form, no gradients).
    With ``mirror``, each motion's left-right mirror image is denoised in the same batch (and,
    in optimisation mode, adapted to as well) and the result is the midpoint of the two
    estimates, mirrored back: the learned prior is not exactly mirror-symmetric, so the two
    differ, and their average is a prior made symmetric. Twice the work.
    ``progress`` receives {"stage": "optimize" | "refine", "step", "steps", "loss"}, and
    {"stage": "denoise", "step", "steps", "phase"} as each phase of the whole is done (the
    windows denoised, stitched, blended, feet locked: a long take's progress inside it).
    With ``guard`` (``mdvae denoise``'s default), a window whose output moved further from
    its input than the input's noise explains falls back to the smoothed input
    (``infer.guard``); each such window is said in its motion's notes and passed to
    ``on_fallback(motion index, start s, end s)`` (times in the motion's own clock).
    ``loops``: per motion, whether it is a cycle to denoise as one (``infer.loop``: tiled three
    times, the middle copy kept and closed at the seam).
    With ``blend`` (``mdvae denoise``'s default), the part of each input's difference from
    its result that the input's own noise does not explain is put back
    (``infer.noise_blend``): a clean take comes back as it came, a noisy one cleaned; each
    motion's :class:`BlendReport` goes to ``on_blend(motion index, report)``; ``blend_fast``
    False puts back the slow band alone (video estimates, whose jitter is not white) and
    bridges short holes by slerp, not a spline through that jitter (``infer.fill.input_curve``).
    With ``feet``, the results' feet are then held still on the floor where they are down
    (``infer.feet.lock_feet``, each input as its source).
    ``fill``: what the inputs' holes (``joint_mask`` False) become, one of
    ``infer.fill.FILLS`` (a "curve" from the frames beside them, the "model"'s frames, or
    "off": as they came); the likelihoods drop them whatever it is. None:
    the model's (as "model"). ``split``: a long hole of every joint cuts its motion into pieces
    denoised on their own, filled from a bridge (``infer.bridge``); False: read as a short one.
    """
    holes = any(has_holes(m) for m in motions)
    reads = denoiser.cfg.reads_holes
    pieces = [observed_pieces(m, MIN_FRAMES, reads) for m in motions] if holes and split else []
    if any(p is not None for p in pieces):  # long holes: the pieces between them on their own
        return denoise_pieces(
            motions, pieces, denoiser, body, window, stride, optimize_steps, lr, batch_size,
            seed, progress, refine, mirror, guard, on_fallback, loops, feet, blend, on_blend,
            blend_fast, fill,
        )  # fmt: skip
    if fill == "off" and holes:  # everything as usual, then the holes as they came
        cleaned = denoise_motions(
            motions, denoiser, body, window, stride, optimize_steps, lr, batch_size, seed,
            progress, refine, mirror, guard, on_fallback, loops, feet, blend, on_blend,
            blend_fast, fill="model", split=split,
        )  # fmt: skip
        return [fill_holes(src, m, "off") for m, src in zip(cleaned, motions, strict=True)]
    if feet is not None:
        cleaned = denoise_motions(
            motions, denoiser, body, window, stride, optimize_steps, lr, batch_size, seed,
            more_phases(progress, 1), refine, mirror, guard, on_fallback, loops, blend=blend,
            on_blend=on_blend, blend_fast=blend_fast, fill=fill, split=split,
        )  # fmt: skip
        out = lock_motions(cleaned, motions, body, feet)
        done = CORE_PHASES + blend + 1
        phase(progress, "feet locked", done, done)
        return out
    if blend:
        cleaned = denoise_motions(
            motions, denoiser, body, window, stride, optimize_steps, lr, batch_size, seed,
            more_phases(progress, 1), refine, mirror, guard, on_fallback, loops,
            fill=None, split=split,
        )  # fmt: skip
        out = []
        for i, (m, src) in enumerate(zip(cleaned, motions, strict=True)):
            blended, report = blend_motion(src, m, blend_fast)
            out.append(fill_holes(src, blended, fill or "model", spline=blend_fast))
            if on_blend is not None:
                on_blend(i, report)
        phase(progress, "blended", CORE_PHASES + 1, CORE_PHASES + 1)
        return out
    if fill not in (None, "model") and holes:
        cleaned = denoise_motions(
            motions, denoiser, body, window, stride, optimize_steps, lr, batch_size, seed,
            progress, refine, mirror, guard, on_fallback, loops, fill=None, split=split,
        )  # fmt: skip
        return [fill_holes(s, m, fill, blend_fast) for m, s in zip(cleaned, motions, strict=True)]
    if loops is not None and any(loops):
        return _denoise_cycles(
            motions, list(loops), denoiser, body, window, stride, optimize_steps, lr,
            batch_size, seed, progress, refine, mirror, guard, on_fallback=on_fallback,
        )  # fmt: skip
    for i, m in enumerate(motions):
        try:
            check_length(m)
        except InputError as exc:
            raise InputError(f"motion {i}: {exc}") from None
    if mirror:
        flipped = [mirror_motion(m, body) for m in motions]
        n = len(motions)
        tell = None if on_fallback is None else lambda i, a, b: on_fallback(i % n, a, b)
        both = denoise_motions(
            [*motions, *flipped], denoiser, body, window, stride, optimize_steps, lr,
            batch_size, seed, progress, refine, guard=guard, on_fallback=tell, split=split,
        )  # fmt: skip
        return [
            average_bodies(a, mirror_motion(b, body))
            for a, b in zip(both[:n], both[n:], strict=True)
        ]
    refining = refine is not None and refine.active
    motions30 = [to_model_rate(m) for m in motions]
    num_windows = sum(len(motion_window_starts(m, window, stride)) for m in motions30)
    observed = optimize_steps > 0 or refining or guard
    fallbacks: list[tuple[int, int]] | None = [] if guard else None
    with threads_for(num_windows, SMALL_BATCH) if optimize_steps == 0 else nullcontext():
        groups = make_windows(
            motions30, denoiser, body, window, stride, observed, points=optimize_steps > 0
        )
        if optimize_steps > 0:
            from mdvae_cli.infer.elbo_fit import fit_denoiser

            tell = staged(progress, "optimize", 0, optimize_steps)
            draws = torch.Generator().manual_seed(seed)  # reproducible whatever ran before
            fit_denoiser(
                denoiser, groups, body, optimize_steps, lr, batch_size, seed, tell,
                sample_generator=draws,
            )  # fmt: skip
        if not refining:
            preds = [predict_windows(denoiser, g, fallbacks=fallbacks) for g in groups]
        else:
            workers = worker_count()
            steps = [len(refine_batches(g, refine, workers)) * refine.steps for g in groups]
            preds = [
                refine_windows(denoiser, g, refine,
                               staged(progress, "refine", done, sum(steps)), fallbacks, workers)
                for g, done in zip(groups, itertools.accumulate([0, *steps]), strict=False)
            ]  # fmt: skip
        phase(progress, "windows denoised", 1, CORE_PHASES)
        out = assemble(motions, motions30, groups, preds)
        phase(progress, "stitched", 2, CORE_PHASES)
    for mi, stretches in fallback_stretches(fallbacks or [], motions30, window).items():
        duration = max((motions30[mi].num_frames - 1) / MODEL_FPS, 1e-9)
        # a new list: the input's is not to change
        out[mi].notes = [*out[mi].notes, guard_note(stretches, duration)]
        if on_fallback is not None:
            for a, b in stretches:
                on_fallback(mi, a, b)
    return out


def _denoise_cycles(motions, loops, denoiser, body, *args, on_fallback=None) -> list[Motion]:
    """:func:`denoise_motions` with the motions flagged in ``loops`` tiled and closed as
    cycles; fallbacks inside a cycle's middle copy are reported on its own clock."""
    from mdvae_cli.infer.loop import COPIES, tile, untile

    tiled = [tile(m) if lp else m for m, lp in zip(motions, loops, strict=True)]

    def tell(i: int, a: float, b: float) -> None:
        if on_fallback is None:
            return
        if not loops[i]:
            on_fallback(i, a, b)
            return
        period = motions[i].num_frames / motions[i].fps
        start = (COPIES // 2) * period
        if b > start and a < start + period:
            on_fallback(i, max(a - start, 0.0), min(b - start, period))

    *head, guard = args
    out = denoise_motions(tiled, denoiser, body, *head, guard=guard, on_fallback=tell)
    return [untile(o, m) if lp else o for o, m, lp in zip(out, motions, loops, strict=True)]
