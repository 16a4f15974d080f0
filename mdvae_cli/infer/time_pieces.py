"""Long takes denoised a piece of time at a time, so that memory stays flat in their length.

Every stage of a denoise (the 30 Hz copy, the windows, the stitch, the blend, the spike and
hole fills, the foot lock) holds a few arrays the size of the take; on a 30-minute 120 Hz take
they add up to gigabytes. A take longer than :data:`PIECE_FRAMES` frames is cut into pieces
of about that many frames, and each piece, with :data:`OVERLAP_SECONDS` of its neighbours on
each side, is denoised on its own (side by side, one per core, on a take of at most
:data:`SIDE_BY_SIDE_PIECES` pieces, :data:`SIDE_BY_SIDE_REFINED` with refinement; else one
after the other); only its result is kept.
Neighbouring results hand over to each other over :data:`FADE_SECONDS` centred on the cut
(slerp of the rotations, lerp of the translation, weights rising smoothly), far from either
piece's edges, where a denoise has less context. A cut is moved off any stretch with missing
frames, so a hole is always filled by one piece that sees both of its sides.

What a piece estimates from its own frames (the input's noise per channel, the floor) is
then estimated over minutes of the take instead of all of it; on a take whose noise does not
change this moves the result by far less than the denoising (``benchmarks/long_takes.py``
quotes the difference, ``tests/test_time_pieces.py`` pins it).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.infer.guard import guard_note, is_guard_note, merged_stretches
from mdvae_cli.infer.noise_blend import BlendReport
from mdvae_cli.infer.progress import progress_of_runs, stoppable
from mdvae_cli.motion.holes import observed
from mdvae_cli.motion.motion import Motion, slice_frames
from mdvae_cli.workers import map_in_order

#: frames in a piece of a long take (4.5 minutes at 120 Hz, 18 at 30 Hz); a take of up to 1.5
#: times this is denoised whole
PIECE_FRAMES = 2**15
#: each piece runs this far into its neighbours
OVERLAP_SECONDS = 8.0
#: and hands over to the next piece over this long, centred on the cut
FADE_SECONDS = 4.0

#: a take of at most this many pieces has them denoised side by side, one per core; a longer
#: one a piece at a time: its own arrays leave no room for a second piece's working memory
#: (about 300 MB at 120 Hz) within 1.5 GB (a 30-minute 120 Hz take: 1,460 MB side by side)
SIDE_BY_SIDE_PIECES = 4
#: the same with latent refinement (``--refine``), whose pieces hold more: side by side, an
#: 18-minute 120 Hz take (4 pieces) peaked at 1,490 MB, a 10-minute one (2) at 1,365 MB
SIDE_BY_SIDE_REFINED = 2

#: ``run(motions, loops, progress, on_fallback, on_blend, piece=False)``:
#: ``infer.denoise_settings.denoise`` on a list of motions with these callbacks; with
#: ``piece``, without the stages that read the whole take (the foot lock)
Run = Callable[..., list[Motion]]


@dataclass(frozen=True)
class PiecePlan:
    """How one take is cut: ``cuts`` are the frames where one piece hands over to the next
    (0 and T at the ends); piece k owns frames [cuts[k], cuts[k+1]) and is denoised over
    ``spans[k]``; ``fade``: the hand-over's length in frames (centred on a cut)."""

    cuts: tuple[int, ...]
    spans: tuple[tuple[int, int], ...]
    fade: int


def plan_pieces(
    observed: np.ndarray,
    fps: float,
    piece: int = PIECE_FRAMES,
    overlap_s: float = OVERLAP_SECONDS,
    fade_s: float = FADE_SECONDS,
) -> PiecePlan | None:
    """The pieces of a take whose frames ``observed`` (T,) are True where no joint is missing;
    None when the take is short enough to denoise whole (<= 1.5 ``piece`` frames) or no cut
    finds a stretch of observed frames to lie in.

    Cuts fall about every ``piece`` frames, each moved to the nearest frame whose overlap
    (``overlap_s`` on both sides) holds no missing frame, within a quarter piece."""
    T = len(observed)
    if T <= piece * 3 // 2:
        return None
    overlap = max(1, round(overlap_s * fps))
    fade = min(max(2, round(fade_s * fps)), overlap)
    count = round(T / piece)
    # free[c]: the frames [c - overlap, c + overlap) are all observed
    missing = np.concatenate([[0], np.cumsum(~np.asarray(observed, bool))])
    centres = np.arange(overlap, T - overlap + 1)
    free = np.zeros(T + 1, dtype=bool)
    free[centres] = missing[centres + overlap] == missing[centres - overlap]
    cuts = [0]
    for k in range(1, count):
        want = round(k * T / count)
        lo = max(0, want - piece // 4)
        near = lo + np.flatnonzero(free[lo : want + piece // 4 + 1])
        if len(near) == 0:
            continue
        c = int(near[np.argmin(np.abs(near - want))])
        if c - cuts[-1] > 2 * overlap:
            cuts.append(c)
    if T - cuts[-1] <= 2 * overlap:
        cuts.pop()
    if len(cuts) < 2:
        return None
    cuts.append(T)
    spans = tuple(
        (max(0, a - overlap), min(T, b + overlap)) for a, b in zip(cuts[:-1], cuts[1:], strict=True)
    )
    return PiecePlan(tuple(cuts), spans, fade)


def fade_in(n: int) -> np.ndarray:
    """Weights rising smoothly from 0 to 1 over n frames, ends excluded (smoothstep).
    -> (n,)"""
    t = (np.arange(n) + 0.5) / n
    return t * t * (3.0 - 2.0 * t)


def hand_over(
    before: np.ndarray, after: np.ndarray, trans_before: np.ndarray, trans_after: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Two results of the same frames, the first handing over to the second (:func:`fade_in`):
    rotations slerped, translations lerped.

    before, after: (n, J, 3) axis-angles; trans_*: (n, 3) -> (n, J, 3), (n, 3)"""
    w = fade_in(before.shape[0])
    q0 = rotvec_to_quat(torch.as_tensor(before, dtype=torch.float64))
    q1 = rotvec_to_quat(torch.as_tensor(after, dtype=torch.float64))
    t = torch.as_tensor(w)[:, None].expand(q0.shape[:-1])
    rot = quat_to_rotvec(quat_slerp(q0, q1, t)).numpy()
    trans = (1.0 - w[:, None]) * trans_before + w[:, None] * trans_after
    return rot, trans


def denoise_in_pieces(
    motions: list[Motion],
    loops: list[bool],
    run: Run,
    progress: Callable[[dict], None] | None = None,
    on_fallback: Callable[[int, float, float], None] | None = None,
    on_blend: Callable[[int, BlendReport], None] | None = None,
    piece: int | None = None,
    finish: Callable[[Motion, Motion], Motion] | None = None,
    side_by_side: int = SIDE_BY_SIDE_PIECES,
) -> list[Motion]:
    """``run(motions, loops, progress, on_fallback, on_blend)`` with each long take that is
    not a cycle (:func:`plan_pieces`) denoised a piece at a time and joined; the short ones
    go to ``run`` together, as they came. Callbacks get whole-take indices and times, one
    blend report per take (the pieces' shares, weighted by the frames each owns) and the
    progress of all the runs as one. ``piece``: frames a piece (None: :data:`PIECE_FRAMES`).
    ``finish(joined, take)``: what a joined take goes through last, on the whole of it (the
    foot lock, whose floor and contacts are the take's: estimated piece by piece, the floor
    moved the feet by up to 4 % of the MPJPE on a 10-minute take, ``benchmarks/time_pieces.py``).
    ``side_by_side``: a take of at most this many pieces has them run side by side, one per
    core (``workers.map_in_order``); a longer one a piece at a time.
    """
    piece = PIECE_FRAMES if piece is None else piece
    plans = [
        None if lp else plan_pieces(observed(m).all(axis=1), m.fps, piece)
        for m, lp in zip(motions, loops, strict=True)
    ]
    if all(p is None for p in plans):
        return run(motions, loops, progress, on_fallback, on_blend)
    whole = [i for i, p in enumerate(plans) if p is None]
    runs = (1 if whole else 0) + sum(len(p.spans) for p in plans if p is not None)
    out: list[Motion | None] = [None] * len(motions)
    done = 0
    if whole:
        results = run(
            [motions[i] for i in whole],
            [loops[i] for i in whole],
            progress_of_runs(progress, done, runs, 1)[0],
            None if on_fallback is None else lambda j, a, b: on_fallback(whole[j], a, b),
            None if on_blend is None else lambda j, r: on_blend(whole[j], r),
        )
        for i, r in zip(whole, results, strict=True):
            out[i] = r
        done += 1
    for i, plan in enumerate(plans):
        if plan is not None:
            workers = 1 if len(plan.spans) > side_by_side else None  # None: every core
            joined = _join(motions[i], plan, run, i, progress, done, runs, on_fallback, on_blend,
                           workers)  # fmt: skip
            out[i] = joined if finish is None else finish(joined, motions[i])
            done += len(plan.spans)
    return out  # type: ignore[return-value]


def _join(m: Motion, plan: PiecePlan, run: Run, index, progress, done, runs, on_fallback,
          on_blend, workers: int | None) -> Motion:  # fmt: skip
    """One take denoised piece by piece (:func:`denoise_in_pieces`), the pieces on
    ``workers`` threads (``workers.map_in_order``; None: one per core, much of a piece's work
    holding one core) and joined in order; what they tell (fallbacks, blend reports) is told
    in the pieces' order."""
    T, fps, half = m.num_frames, m.fps, plan.fade // 2
    rot = trans = mask = None
    stretches: list[tuple[float, float]] = []
    shares, told = np.zeros(2), False
    notes: list[str] = list(m.notes)
    tells = progress_of_runs(progress, done, runs, len(plan.spans))
    stop = threading.Event()  # set when the pieces side by side are left (Ctrl-C)

    def piece(k: int):
        lo, hi = plan.spans[k]
        falls: list[tuple[float, float]] = []
        reports: list[BlendReport] = []
        part = slice_frames(m, lo, hi)
        part.notes = list(m.notes)
        r = run([part], [False], stoppable(tells[k], stop), lambda _j, a, b: falls.append((a, b)),
                lambda _j, rep: reports.append(rep), True)[0]  # fmt: skip
        return r, falls, reports

    pieces = map_in_order(piece, range(len(plan.spans)), workers, stop)
    for k, (r, falls, reports) in enumerate(pieces):
        lo = plan.spans[k][0]
        own_a, own_b = plan.cuts[k], plan.cuts[k + 1]
        for a, b in falls:
            a, b = max(a + lo / fps, own_a / fps), min(b + lo / fps, own_b / fps)
            if b > a:
                stretches.append((a, b))
                if on_fallback is not None:
                    on_fallback(index, a, b)
        for rep in reports:
            shares += (own_b - own_a) * np.array([rep.input_share, rep.spike_share])
        told |= bool(reports)
        notes += [n for n in r.notes if n not in notes and not is_guard_note(n)]
        rk, tk = r.joint_rotations, np.asarray(r.trans, np.float64)
        if rot is None:
            rot = np.empty((T, *rk.shape[1:]), dtype=r.pose_body.dtype)
            trans = np.empty((T, 3), dtype=r.trans.dtype)
            mask = None if r.joint_mask is None else np.ones((T, r.joint_mask.shape[1]), bool)
        # this piece writes from its hand-over with the last one (whose frames are there) to
        # the end of its hand-over with the next
        a = 0 if k == 0 else own_a - half
        b = T if k == len(plan.spans) - 1 else own_b + half
        if k > 0:
            fade = slice(a, own_a + half)
            ours = slice(fade.start - lo, fade.stop - lo)
            faded = hand_over(rot[fade], rk[ours], trans[fade], tk[ours])
        rot[a:b], trans[a:b] = rk[a - lo : b - lo], tk[a - lo : b - lo]
        if k > 0:
            rot[fade], trans[fade] = faded
        if mask is not None and r.joint_mask is not None:
            mask[own_a:own_b] = r.joint_mask[own_a - lo : own_b - lo]
        del r, rk, tk
    joined = m.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)
    joined.joint_mask = mask if mask is not None else m.joint_mask
    if stretches:
        notes.append(guard_note(merged_stretches(stretches), m.duration))
    joined.notes = notes
    if on_blend is not None and told:
        input_share, spike_share = shares / T
        on_blend(index, BlendReport(float(input_share), float(spike_share)))
    return joined
