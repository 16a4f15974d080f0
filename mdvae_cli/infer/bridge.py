"""Long holes bridged: a hole that splits a take (``infer.fill.observed_pieces``) is filled
from the take denoised again around it with the hole read as one.

The pieces either side of a long hole are denoised on their own (the networks never read its
placeholders), so their frames beside it have context on one side only: their ends are what
the pieces' denoising makes of one-sided windows, and the curve drawn from them over the hole
(``infer.fill``) swings with their last frames' velocities. A *bridge* is the stretch from
:data:`BRIDGE_CONTEXT_SECONDS` before the hole to as far after it, denoised whole with the hole
marked missing (its likelihood drops the placeholders, as it does a short hole's): its frames
beside the hole see both sides. The hole's fill is drawn from the bridge's frames and then
turned, joint by joint, so that it meets the pieces' own frames at both ends (the offset at
each end, slerped across the hole): the observed frames stay exactly as the pieces made them.

On the corpus's clips with Pose-NDF noise (σ 0.10), the fill of 15-, 30- and 60-frame holes
came 16 / 14 / 3 % closer to the clean motion on test and 13 / 6 / 2 % on unseen_test than the
curve from the pieces' ends (docs/model.md, "Long holes bridged"); a clean take's holes are
filled from its own frames as before (``infer.fill.result_shares``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.geometry.rotations import quat_multiply, quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.infer.feet import FootLockConfig, lock_motions
from mdvae_cli.infer.fill import fill_holes, join_pieces, mix_curves, result_curve
from mdvae_cli.motion.holes import observed
from mdvae_cli.motion.motion import Motion, slice_frames

#: the context each side of a long hole that its bridge denoises with it (seconds): more
#: than the denoiser's 2 s window, so the frames beside the hole are read from both sides
BRIDGE_CONTEXT_SECONDS = 2.0


def bridged_holes(
    num_frames: int, fps: float, pieces: list[tuple[int, int]]
) -> list[tuple[int, int, int, int]]:
    """The long holes between consecutive pieces [a, b) and their bridges: (bridge start,
    hole start, hole end, bridge end), the hole [hole start, hole end) the frames between the
    two pieces, the bridge that plus :data:`BRIDGE_CONTEXT_SECONDS` each side, within the
    take. Holes before the first piece or after the last have one side only: no bridge."""
    context = int(round(BRIDGE_CONTEXT_SECONDS * fps))
    out = []
    for (_, end), (start, _) in zip(pieces, pieces[1:], strict=False):
        if start > end:
            out.append((max(0, end - context), end, start, min(num_frames, start + context)))
    return out


def bridge_spans(holes: list[tuple[int, int, int, int]]) -> list[tuple[int, int]]:
    """The bridges' frames [start, end), overlapping ones merged: the stretches to denoise."""
    spans: list[list[int]] = []
    for a, _, _, b in holes:
        if spans and a <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], b)
        else:
            spans.append([a, b])
    return [(a, b) for a, b in spans]


def with_bridges(joined: Motion, spans: list[tuple[int, int]], results: list[Motion]) -> Motion:
    """``joined`` (the pieces' result) with each bridge's frames [a, b) taken from its result:
    the context a hole's fill is drawn from."""
    rot = joined.joint_rotations.copy()
    trans = np.array(joined.trans, dtype=np.float64)
    for (a, b), r in zip(spans, results, strict=True):
        rot[a:b] = r.joint_rotations
        trans[a:b] = r.trans
    return joined.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)


def meet_ends(
    filled: Motion, from_bridge: Motion, holes: list[tuple[int, int, int, int]]
) -> Motion:
    """``filled`` (the take with every hole filled, its observed frames the pieces') with the
    missing entries of each bridged hole taken from ``from_bridge`` (the same take filled from
    its bridges), turned to meet ``filled`` at the hole's ends: per joint, the rotation from
    the bridge's frame to ``filled``'s on the frame before the hole and on the frame after it,
    slerped across the hole and put before the bridge's rotations (the translation: the two
    offsets, lerped)."""
    miss = ~observed(filled)
    rot = filled.joint_rotations.copy()
    trans = np.array(filled.trans, dtype=np.float64)
    rot_b = from_bridge.joint_rotations
    trans_b = np.asarray(from_bridge.trans, dtype=np.float64)
    for _, a, b, _ in holes:
        n = b - a
        w = torch.arange(1, n + 1, dtype=torch.float64)[:, None] / (n + 1)  # (n, 1)
        q = rotvec_to_quat(torch.as_tensor(rot[[a - 1, b]], dtype=torch.float64))  # (2, 22, 4)
        qb = rotvec_to_quat(torch.as_tensor(rot_b[[a - 1, b]], dtype=torch.float64))
        turn = quat_multiply(q, qb * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=torch.float64))
        across = quat_slerp(turn[0].expand(n, -1, -1), turn[1].expand(n, -1, -1), w)
        inside = rotvec_to_quat(torch.as_tensor(rot_b[a:b], dtype=torch.float64))
        turned = quat_to_rotvec(quat_multiply(across, inside)).numpy()
        rot[a:b] = np.where(miss[a:b, :, None], turned, rot[a:b])
        shift = trans[[a - 1, b]] - trans_b[[a - 1, b]]
        wt = w.numpy()
        moved = trans_b[a:b] + (1 - wt) * shift[0] + wt * shift[1]
        trans[a:b] = np.where(miss[a:b, :1], moved, trans[a:b])
    dtype = filled.pose_body.dtype
    return filled.with_body(
        root_orient=rot[:, 0].astype(dtype),
        pose_body=rot[:, 1:].astype(dtype),
        trans=trans.astype(filled.trans.dtype),
    )


def bridge_fills(
    motions: list[Motion],
    pieces: list[list[tuple[int, int]] | None],
    joined: list[Motion],
    method: str,
    denoise_stretches: Callable[[list[Motion]], list[Motion]],
    spline: bool = True,
) -> list[Motion]:
    """Each motion's holes filled by ``method`` (``infer.fill.fill_holes``) from ``joined``
    (its pieces' result), its long holes between two pieces from their bridges
    (:func:`meet_ends`). ``denoise_stretches`` denoises the bridges (whole: the holes in them
    read as missing, not split), all of them in one call. ``spline``: the input's own curve
    over short holes a spline, else slerp (``infer.fill.input_curve``)."""
    plans, stretches = [], []
    for m, cuts in zip(motions, pieces, strict=True):
        holes = bridged_holes(m.num_frames, m.fps, cuts) if cuts else []
        spans = bridge_spans(holes)
        plans.append((holes, spans))
        stretches += [slice_frames(m, a, b) for a, b in spans]
    done = denoise_stretches(stretches) if stretches else []
    out, k = [], 0
    for m, result, (holes, spans) in zip(motions, joined, plans, strict=True):
        if not holes:
            out.append(fill_holes(m, result, method, spline))
            continue
        context = with_bridges(result, spans, done[k : k + len(spans)])
        k += len(spans)
        # each hole's curve drawn once: the bridged ones from the bridges, the rest from the
        # pieces' result (meet_ends takes the bridged holes' entries alone from the bridges)
        starts = {a for _, a, _, _ in holes}
        pieces_curve = result_curve(m, result, method, lambda a, bridged=starts: a not in bridged)
        bridge_curve = result_curve(m, context, method, starts.__contains__)
        own = meet_ends(pieces_curve, bridge_curve, holes)
        out.append(mix_curves(m, own, method, spline))
    return out


def lock_bridged(
    filled: list[Motion],
    motions: list[Motion],
    pieces: list[list[tuple[int, int]] | None],
    body: BodyModel,
    feet: FootLockConfig,
) -> list[Motion]:
    """The foot lock on takes filled by :func:`bridge_fills`: the pieces' frames locked piece by
    piece (each piece a take of its own, as it was denoised: the frames the take has come back
    as they did before bridges), each long hole's from the whole take locked (its feet held
    through the hole), turned to meet the pieces' at its ends (:func:`meet_ends`)."""
    whole = lock_motions(filled, motions, body, feet)
    out = []
    for f, w, m, cuts in zip(filled, whole, motions, pieces, strict=True):
        if not cuts:
            out.append(w)
            continue
        kept = _locked_pieces(f, m, cuts, body, feet)
        out.append(meet_ends(kept, w, bridged_holes(m.num_frames, m.fps, cuts)))
    return out


def lock_pieces(
    joined: list[Motion],
    motions: list[Motion],
    pieces: list[list[tuple[int, int]] | None],
    body: BodyModel,
    feet: FootLockConfig,
) -> list[Motion]:
    """The foot lock on the pieces alone, each a take of its own (as :func:`lock_bridged`
    locks them), the frames between them as they are: a take whose holes stay as they came
    (``--fill off``). A motion without pieces (None) is locked whole."""
    return [
        _locked_pieces(j, m, cuts, body, feet) if cuts else lock_motions([j], [m], body, feet)[0]
        for j, m, cuts in zip(joined, motions, pieces, strict=True)
    ]


def _locked_pieces(
    f: Motion, m: Motion, cuts: list[tuple[int, int]], body: BodyModel, feet: FootLockConfig
) -> Motion:
    """``f`` with each piece [a, b) of ``cuts`` locked on its own (``m``'s piece its source)."""
    parts = lock_motions([slice_frames(f, a, b) for a, b in cuts],
                         [slice_frames(m, a, b) for a, b in cuts], body, feet)  # fmt: skip
    return join_pieces(f, cuts, parts)
