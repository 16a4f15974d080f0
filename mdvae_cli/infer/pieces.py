"""A take cut by long holes (``infer.fill.observed_pieces``): its pieces denoised on their
own, put back, its holes filled (the long ones from their bridges, ``infer.bridge``) and its
feet locked. ``infer.denoise.denoise_motions`` hands such takes here."""

from __future__ import annotations

from mdvae_cli.infer.bridge import bridge_fills, lock_bridged, lock_pieces
from mdvae_cli.infer.fill import fill_holes, join_pieces
from mdvae_cli.infer.progress import CORE_PHASES, more_phases, phase
from mdvae_cli.motion.motion import Motion, slice_frames


def denoise_pieces(motions, pieces, denoiser, body, *args) -> list[Motion]:
    """Denoise the pieces of the motions between their long holes on their own, put them
    back, fill the holes, the long ones from their bridges (the "learned" fill's networks
    never saw long holes: the "curve" fills such a take), then lock the feet of the whole.
    With the fill "off" no bridge is denoised: the pieces' frames locked piece by piece, the
    holes as they came. ``pieces``: per motion, ``observed_pieces``' list or None (no long
    hole). ``args``: ``denoise_motions``' arguments after ``body``."""
    from mdvae_cli.infer.denoise import denoise_motions

    *head, on_fallback, loops, feet, blend, on_blend, blend_fast, fill = args
    off = fill == "off"
    progress = head[6]  # the pieces' run: its phases, then the holes' fill and the lock
    steps = CORE_PHASES + blend + (not off) + (feet is not None)
    head[6] = more_phases(progress, steps - CORE_PHASES - blend)
    parts, owners = [], []
    for i, (m, cuts) in enumerate(zip(motions, pieces, strict=True)):
        for a, b in cuts if cuts is not None else [(0, m.num_frames)]:
            parts.append(slice_frames(m, a, b))
            owners.append((i, a / m.fps))
    tell = None if on_fallback is None else (
        lambda j, a, b: on_fallback(owners[j][0], a + owners[j][1], b + owners[j][1]))  # fmt: skip
    report = None if on_blend is None else lambda j, r: on_blend(owners[j][0], r)
    done = denoise_motions(
        parts, denoiser, body, *head, on_fallback=tell,
        loops=None, blend=blend,  # a piece of a take is no cycle
        on_blend=report, blend_fast=blend_fast,
        fill="model" if off else fill,  # "off": the short holes filled for the lock to read
    )  # fmt: skip
    joined, k = [], 0
    for m, cuts in zip(motions, pieces, strict=True):
        cuts = cuts if cuts is not None else [(0, m.num_frames)]
        joined.append(join_pieces(m, cuts, done[k : k + len(cuts)]))
        k += len(cuts)
    if off:
        if feet is not None:
            joined = lock_pieces(joined, motions, pieces, body, feet)
            phase(progress, "feet locked", steps, steps)
        return [fill_holes(m, j, "off") for m, j in zip(motions, joined, strict=True)]
    window, stride, _, lr, batch_size, seed, _, refine, mirror, guard = head

    def bridges(stretches: list[Motion]) -> list[Motion]:  # the networks are fitted already
        return denoise_motions(
            stretches, denoiser, body, window, stride, 0, lr, batch_size, seed, None, refine,
            mirror, guard, blend=blend, blend_fast=blend_fast, fill="model",
            split=False,
        )  # fmt: skip

    method = "curve" if fill == "learned" else fill or "model"
    out = bridge_fills(motions, pieces, joined, method, bridges, spline=blend_fast)
    phase(progress, "holes filled", CORE_PHASES + blend + 1, steps)
    if feet is None:
        return out
    out = lock_bridged(out, motions, pieces, body, feet)
    phase(progress, "feet locked", steps, steps)
    return out
