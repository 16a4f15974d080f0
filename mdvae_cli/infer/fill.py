"""Holes (frames and joints a take is missing, ``Motion.joint_mask`` False) in the denoised
result: how they are written, and what the later stages read of the input there.

The denoiser reads placeholders in the holes (``motion.holes.fill_gaps``) and its likelihoods
drop them (the joint mask weighs the observations). What ends up in a hole is then one of
:data:`FILLS`:

* ``"curve"``: per joint, a cubic spline through the input's own frames and a cubic Hermite
  curve from the values and velocities of the *result's* frames beside the hole
  (``motion.holes.fill_gaps``), each replaced over a long hole of every joint by a stretch of
  the same frames that matches the hole's ends, where one does (``motion.pattern``), and
  mixed by the input's own noise (:func:`mix_by_noise`): a clean take is filled from its own
  frames, a noisy one from its cleaned frames;
* ``"learned"``: as ``"curve"``, with the denoiser's own frames in place of the curve from
  the result's frames: the default for networks fitted to read holes (``fit-dataset
  --holes``), which fill them from the prior and the frames around them;
* ``"model"``: the denoiser's own frames (its prior's continuation of the placeholders);
* ``"off"``: the input's values as they came.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat, rotvec_unwrap
from mdvae_cli.infer.fill_choices import FILLS
from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.motion.holes import fill_gaps, observed
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.pattern import pattern_fill


def has_holes(motion: Motion) -> bool:
    """Whether any body joint of any frame is missing."""
    return motion.joint_mask is not None and not np.asarray(motion.joint_mask, bool).all()


def fill_holes(
    source: Motion, result: Motion, method: str = "curve", spline: bool = True
) -> Motion:
    """``result`` (the denoised ``source``, same frames) with the source's holes written by
    ``method`` (see the module docstring); the result's mask is the source's. ``spline``:
    the input's own curve over short holes is a spline through its frames (:func:`input_curve`;
    False: slerp / lerp, for a video estimate)."""
    if method not in FILLS:
        raise ValueError(f"fill must be one of {', '.join(FILLS)}, got {method!r}")
    if not has_holes(source):
        return result
    if method == "off":
        out = result.with_body()
        out.joint_mask = observed(source)
        return take_holes(out, source, out.joint_mask)
    return mix_curves(source, result_curve(source, result, method), method, spline)


def result_curve(
    source: Motion, result: Motion, method: str, which: Callable[[int], bool] | None = None
) -> Motion:
    """``result`` with the source's holes drawn from its own frames, as ``method`` draws them:
    "curve", a stretch of the cleaned take that matches the hole's ends where one does, the
    Hermite curve from its frames beside the hole elsewhere; "learned" and "model", the
    result's own frames. The mask is the source's. ``which``: whether the long hole that
    starts at a frame is searched for a matching stretch (None: each one; the others keep
    the Hermite curve: a caller that writes them from elsewhere)."""
    out = result.with_body()
    out.joint_mask = observed(source)
    if method == "curve":
        return pattern_fill(out, fill_gaps(out, "hermite", RESULT_TANGENT_FRAMES), which)[0]
    return out


def mix_curves(source: Motion, from_result: Motion, method: str, spline: bool = True) -> Motion:
    """The holes' curve from the result (:func:`result_curve`) mixed with the input's own
    (:func:`input_curve`) by the input's noise (:func:`mix_by_noise`), as ``method`` mixes
    them ("model": the result's alone)."""
    if method == "model":
        return from_result
    return mix_by_noise(input_curve(source, spline), from_result, source)


#: the input noise (rad per component, m for the translation) at which a hole's curve reads
#: the input's frames and the result's equally: below it the input's own frames (a clean take,
#: whose result differs from it by the denoiser's hair), above it the cleaned ones
CURVE_NOISE_RAD = 0.01
#: the take's noise (rad, the median of its joints') under which it reads as clean, its holes
#: filled from its own frames whatever one fast joint's noise reads (:func:`result_shares`)
TAKE_NOISE_RAD = 0.012
CURVE_NOISE_M = 0.003
#: the curve from a denoised result holds its end velocities over holes up to this long
#: (frames; ``motion.holes.TANGENT_FRAMES`` for the input's own frames): a denoised velocity
#: is less sure than a clean take's
RESULT_TANGENT_FRAMES = 15
#: the curve through the input's own frames is a cubic spline through all of them for holes
#: up to this long (seconds; a clean take's exact neighbours), the Hermite curve over longer
#: ones (a spline swings over a long hole: the root's turn most)
SPLINE_SECONDS = 1.0


def mix_by_noise(from_input: Motion, from_result: Motion, source: Motion) -> Motion:
    """Per joint, the hole curves drawn from the input's frames and from the result's, mixed
    by the input's own noise (:func:`result_shares`). Outside the holes, ``from_result``."""
    share, share_t = result_shares(source)
    rot_in = from_input.joint_rotations
    rot_res = from_result.joint_rotations
    w = torch.as_tensor(share)[None].expand(len(rot_in), -1)
    q = quat_slerp(rotvec_to_quat(torch.as_tensor(rot_in, dtype=torch.float64)),
                   rotvec_to_quat(torch.as_tensor(rot_res, dtype=torch.float64)), w)  # fmt: skip
    miss = ~observed(source)
    rot = np.where(miss[..., None], quat_to_rotvec(q).numpy(), rot_res)
    trans = (1 - share_t) * np.asarray(from_input.trans, float) + share_t * np.asarray(
        from_result.trans, float
    )
    trans = np.where(miss[:, :1], trans, from_result.trans)
    return from_result.with_body(
        root_orient=rot[:, 0].astype(from_result.root_orient.dtype),
        pose_body=rot[:, 1:].astype(from_result.pose_body.dtype),
        trans=trans.astype(from_result.trans.dtype),
    )


def result_shares(source: Motion, unwrapped: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The result curve's share in each joint's holes and in the translation's.

    A joint's share is s^4 / (s^4 + c^4) for its own noise s (``noise_variance`` of its
    frames; c = :data:`CURVE_NOISE_RAD`), times S^8 / (S^8 + C^8) for the take's noise S, the
    median of the joints' (C = :data:`TAKE_NOISE_RAD`). The joint's own noise says which of
    a noisy take's joints are noisier; the take's says whether it is noisy at all. A clean
    take's fast joints bend their third differences as noise does (per joint up to 0.035 rad
    on clean unseen_test clips), but most of its joints are still (the median 0.0005–0.0084
    rad there, 0.020–0.024 under Pose-NDF noise of 0.02 rad), so a clean take is filled from
    its own frames, joint by joint, as a studio's spline fill would.
    The translation's share is t^4 / (t^4 + :data:`CURVE_NOISE_M`^4) for its own noise t.

    unwrapped: the source's rotation vectors unwrapped in time (T, 22, 3), when at hand.
    -> ((22,) shares, the translation's)"""
    seen = observed(source)
    if unwrapped is None:
        src = torch.as_tensor(source.joint_rotations, dtype=torch.float64)
        unwrapped = rotvec_unwrap(src, 0).numpy()
    s2 = noise_variance(unwrapped, seen)
    take2 = float(np.median(s2))
    share = s2**2 / (s2**2 + CURVE_NOISE_RAD**4) * take2**4 / (take2**4 + TAKE_NOISE_RAD**8)
    t2 = float(noise_variance(np.asarray(source.trans, float)[:, None, :], seen[:, :1])[0])
    return share, t2**2 / (t2**2 + CURVE_NOISE_M**4)


def fill_spikes(
    source: Motion,
    blended: Motion,
    spikes: np.ndarray,
    trans_spikes: np.ndarray,
    unwrapped: np.ndarray | None = None,
) -> Motion:
    """``blended`` (the blend of ``source``'s denoised motion) with the source's spikes (T, 22)
    and its translation's (T,) filled as short holes: a spike is an observation the input
    does not have. Per joint, the cubic through the two observed frames each side of it (the
    input's own curve, a studio's spline fill) and the blended frame are mixed as a hole's
    curves are (:func:`result_shares`, on the input's frames without its spikes): a clean
    take's spike is filled from its own frames (a glitch, or a fast flick the spike rule
    mistakes for one: either way nearer the take than the denoiser's frame, which on fast
    motion can be tens of degrees off), a noisy take's keeps the denoiser's frame. Vectorised
    over spikes (a clean take of fast motion has one every ~300 joint-frames). The result
    keeps ``blended``'s mask; a spike without two observed frames on each side within
    :data:`SPIKE_SPAN` frames keeps the blended frame. unwrapped: the source's rotation
    vectors unwrapped in time (T, 22, 3), when at hand (the blend's)."""
    seen = observed(source)
    marked = source.with_body()
    marked.joint_mask = seen & ~spikes & ~trans_spikes[:, None]
    share, share_t = result_shares(marked, unwrapped)
    rot_src = source.joint_rotations
    rot = blended.joint_rotations.copy()
    for j in np.flatnonzero(spikes.any(axis=0)):
        frames, idx, weights = _cubic_stencils(seen[:, j] & ~spikes[:, j], spikes[:, j])
        if len(frames) == 0:
            continue
        q = rotvec_to_quat(torch.as_tensor(rot_src[idx, j], dtype=torch.float64))  # (n, 4, 4)
        q = torch.where((q * q[:, 1:2]).sum(-1, keepdim=True) < 0, -q, q)
        curve = (torch.as_tensor(weights)[..., None] * q).sum(1)
        curve = curve / curve.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        here = rotvec_to_quat(torch.as_tensor(rot[frames, j], dtype=torch.float64))
        rot[frames, j] = quat_to_rotvec(quat_slerp(curve, here, float(share[j]))).numpy()
    trans = np.array(blended.trans, dtype=np.float64)
    frames, idx, weights = _cubic_stencils(seen[:, 0] & ~trans_spikes, trans_spikes)
    if len(frames):
        curve_t = (weights[..., None] * np.asarray(source.trans, np.float64)[idx]).sum(1)
        trans[frames] = (1 - share_t) * curve_t + share_t * trans[frames]
    dtype = blended.pose_body.dtype
    return blended.with_body(
        root_orient=rot[:, 0].astype(dtype),
        pose_body=rot[:, 1:].astype(dtype),
        trans=trans.astype(blended.trans.dtype),
    )


#: a spike is filled from observed frames at most this far apart around it (frames)
SPIKE_SPAN = 8


def _cubic_stencils(seen: np.ndarray, spikes: np.ndarray):
    """For the frames of one channel where ``spikes`` (T,) is True: the Lagrange cubic through
    the two frames of ``seen`` (T,) before and the two after each, when they span at most
    :data:`SPIKE_SPAN` frames.  -> (those frames (n,), their stencils' frames (n, 4), weights
    (n, 4))"""
    obs = np.flatnonzero(seen)
    frames = np.flatnonzero(spikes)
    k = np.searchsorted(obs, frames)
    ok = (k >= 2) & (k + 1 < len(obs))
    frames, k = frames[ok], k[ok]
    idx = np.stack([obs[k - 2], obs[k - 1], obs[k], obs[k + 1]], axis=1)
    near = idx[:, 3] - idx[:, 0] <= SPIKE_SPAN
    frames, idx = frames[near], idx[near]
    t = idx.astype(float)
    x = frames.astype(float)[:, None]
    w = np.ones((len(frames), 4))
    for i in range(4):
        for m in range(4):
            if m != i:
                w[:, i] *= (x[:, 0] - t[:, m]) / (t[:, i] - t[:, m])
    return frames, idx, w


def input_curve(source: Motion, spline: bool = True) -> Motion:
    """The holes of ``source`` filled from its own frames: the spline over short holes, the
    Hermite curve over long ones (:data:`SPLINE_SECONDS`), joint by joint; a long hole of
    every joint from a stretch of the take that matches its ends, where one does
    (``motion.pattern``). ``spline`` False: slerp / lerp over the short holes instead (a video
    estimate's frames beside a hole carry jitter that is not white, spikes and swapped legs,
    which a spline through every frame swings with)."""
    short, hermite = (
        fill_gaps(source.with_body(), "spline" if spline else "slerp"),
        fill_gaps(source.with_body(), "hermite"),
    )
    longest = max(2, int(round(SPLINE_SECONDS * source.fps)))
    missing = ~observed(source)
    long = np.zeros_like(missing)
    for j in np.flatnonzero(missing.any(axis=0)):
        edges = np.diff(np.concatenate([[0], missing[:, j].astype(int), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            long[a:b, j] = b - a > longest
    return pattern_fill(source, take_holes(short, hermite, ~long))[0]


def take_holes(motion: Motion, other: Motion, mask: np.ndarray) -> Motion:
    """``motion`` with its entries where ``mask`` (T, 22) is False taken from ``other`` (the
    root translation follows the pelvis)."""
    miss = ~np.asarray(mask, bool)
    rot = motion.joint_rotations
    rot_other = other.joint_rotations
    rot = np.where(miss[..., None], rot_other.astype(rot.dtype), rot)
    trans = np.where(miss[:, :1], np.asarray(other.trans, motion.trans.dtype), motion.trans)
    return motion.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)


def holes_from(source: Motion, result: Motion) -> Motion:
    """``source`` with its holes taken from ``result`` (what a later stage reads as the input
    there: the foot lock finds contacts on the filled motion); ``source`` itself when whole."""
    return take_holes(source, result, observed(source)) if has_holes(source) else source


#: a run of frames missing every joint this long (seconds) or longer splits the take: the
#: pieces either side are denoised on their own, never reading the placeholders between them
SPLIT_SECONDS = 0.3
#: the same for networks that read where the holes are (``DenoiserConfig.reads_holes``):
#: they were fitted to whole-frame holes up to ``motion.holes.RANDOM_FRAME_HOLES``' longest
READ_SPLIT_SECONDS = 1.5


def observed_pieces(
    motion: Motion, least: int, reads_holes: bool = False
) -> list[tuple[int, int]] | None:
    """[start, end) of the runs of frames between the motion's long whole-frame holes (at
    least :data:`SPLIT_SECONDS`, or :data:`READ_SPLIT_SECONDS` for networks that read holes)
    that hold ``least`` frames at 30 Hz or more; None when it has no such hole (nothing to
    split)."""
    split = READ_SPLIT_SECONDS if reads_holes else SPLIT_SECONDS
    min_frames = int(np.ceil((least - 1) * motion.fps / 30.0)) + 1
    if not has_holes(motion):
        return None
    gone = ~observed(motion).any(axis=1)
    long_gap = max(2, int(round(split * motion.fps)))
    edges = np.diff(np.concatenate([[0], gone.astype(int), [0]]))
    gaps = [(a, b) for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                                   strict=True) if b - a >= long_gap]  # fmt: skip
    if not gaps:
        return None
    bounds = [0, *[x for gap in gaps for x in gap], motion.num_frames]
    pieces = list(zip(bounds[::2], bounds[1::2], strict=True))
    return [(a, b) for a, b in pieces if b - a >= min_frames]


def join_pieces(source: Motion, pieces: list[tuple[int, int]], results: list[Motion]) -> Motion:
    """``source`` with each piece's frames [a, b) taken from its result (the rest, holes and
    pieces too short to denoise, as they came)."""
    rot = source.joint_rotations.copy()
    trans = np.array(source.trans, dtype=np.float64)
    for (a, b), r in zip(pieces, results, strict=True):
        rot[a:b] = r.joint_rotations
        trans[a:b] = r.trans
    out = source.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)
    out.notes = [*source.notes, *(n for r in results for n in r.notes if n not in source.notes)]
    return out
