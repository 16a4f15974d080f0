"""What the input's own noise does not explain stays as it came.

The denoiser's output is a second estimate of the motion beside the input itself. Where the
input is clean, the input is the better estimate; where it is noisy, the denoiser's. Their best
mix frame by frame (noise and the denoiser's error independent) is

    x = y + g (x_hat - y),   g = s^2 / (s^2 + e^2) = s^2 / E|x_hat - y|^2,

with s^2 the input's noise variance and e^2 the denoiser's error variance: E|x_hat - y|^2 =
s^2 + e^2. So the change the denoiser made is kept in full only where the input's own noise
explains it, and shrunk where it is more than the noise: a clean take comes back nearly as it
came, a noisy one cleaned. Per joint (each joint has its own noise: a video tracker's wrists
jitter more than its pelvis) and per stretch of about a second (the denoiser errs more on some
moves than on others).

The input's noise is measured on the input alone (``infer.input_noise``), from its third
differences in time: white noise of variance s^2 gives third differences of variance 20 s^2,
while a smooth motion's third differences are small at any rate of 24 Hz and up; the median
keeps fast moves from inflating it. Spikes (a marker swap, a solver flip) are not white
noise: a frame that jumps away from both of its neighbours by far more than the noise is an
outlier of the input: an observation it does not have, filled as a short hole
(``infer.fill.fill_spikes``: the take's own curve through it in a clean take, the denoiser's
frame in a noisy one).

Pure numpy/torch math on arrays of one motion: rotations (T, J, 3) axis-angle, translation
(T, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mdvae_cli.filters import CACHE_FRAMES, correlate_frames, gaussian_coefficients
from mdvae_cli.geometry.rotations import rotvec_to_quat, rotvec_unwrap
from mdvae_cli.geometry.rotations_np import rotvec_product
from mdvae_cli.infer.fill import TAKE_NOISE_RAD, fill_spikes
from mdvae_cli.infer.input_noise import ONE_AXIS_MARGIN, component_noise_variance, noise_variance
from mdvae_cli.infer.spike_worlds import keep_worlds_below_spikes
from mdvae_cli.infer.spikes import SPIKE_FLOOR_M, SPIKE_FLOOR_RAD, spike_frames
from mdvae_cli.motion.holes import observed
from mdvae_cli.motion.motion import Motion

#: the stretch over which the denoiser's change is measured (seconds)
BLEND_SECONDS = 1.0
#: the slow and fast bands are split by a Gaussian of this width (seconds)
BAND_SECONDS = 0.05
#: how many times its noise variance a band's residual must exceed before any is put back
SLOW_MARGIN = 1.0
FAST_MARGIN = 3.0
#: ... and where the fast band is not blended (a video take, whose tracker jitter is not
#: white), it is still put back where its residual exceeds its noise variance this many times
#: (ten times the noise's spread): there the denoiser went wrong, not the tracker (on video-like
#: noise an unseen dance, CMU 05_06, came back 14 cm off against the input's 10 without it)
GONE_MARGIN = 100.0
#: a noisy take's translation noise on one axis (a retarget's pelvis height) is read at its
#: share from this many times the pooled median (rotations: ``input_noise.ONE_AXIS_MARGIN``)
TRANS_AXIS_MARGIN = 2.0
#: ... and a noisy take's rotation noise on fewer than three axes (a retarget's knee hinge) from
#: this many: a BVH rider's (CMU motorcycle at 120 Hz, sigma 0.1) left knee read 9.2 times its
#: still axes' level, under ``ONE_AXIS_MARGIN``, and kept its noise (342 m/s^2, the right 6);
#: three equally noisy axes read 0.5-1.9 (a clean take's axes keep ``ONE_AXIS_MARGIN``)
NOISY_AXIS_MARGIN = 2.0


@dataclass
class BlendReport:
    """How much of a motion came back as it came: ``input_share`` is the mean share of the
    input's slow difference from the denoiser's output that was put back (0 = the denoiser's
    motion, 1 = the input's), ``spike_share`` the share of frames where the input had a spike
    in a rotation (filled there as a short hole, :func:`blend_motion`)."""

    input_share: float
    spike_share: float


def moving_mean(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average along axis 0 over ``width`` frames (shorter at the ends).

    x: (T, ...) -> (T, ...)"""
    T = x.shape[0]
    h = max(0, width // 2)
    c = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, axis=0)])
    lo = np.clip(np.arange(T) - h, 0, T)
    hi = np.clip(np.arange(T) + h + 1, 0, T)
    n = (hi - lo).reshape(-1, *([1] * (x.ndim - 1)))
    return (c[hi] - c[lo]) / n


def smooth_in_time(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Convolve along axis 0 with edge values repeated, by a symmetric kernel (odd length;
    ``filters.correlate_frames``).  x: (T, ...) -> (T, ...)"""
    r = len(kernel) // 2
    padded = np.concatenate([np.repeat(x[:1], r, 0), x, np.repeat(x[-1:], r, 0)])
    return correlate_frames(padded, kernel)


def kept_share(
    residual_sq: np.ndarray, noise_var: np.ndarray, width: int, seen: np.ndarray | None = None
) -> np.ndarray:
    """The share of a band of the residual that its noise does not explain, per frame and
    channel: 1 - s^2 / E|r|^2, in [0, 1].

    residual_sq: (T, C) squared residual per component; noise_var: (C,) the band's noise
    variance per component; width: frames over which E is taken; seen: (T, C) where the
    input has values (E over those alone), or None -> (T, C)"""
    if seen is None:
        local = moving_mean(residual_sq, width)
    else:
        local = moving_mean(residual_sq * seen, width) / np.maximum(moving_mean(seen, width), 1e-6)
    return np.clip(1.0 - noise_var[None] / np.maximum(local, 1e-12), 0.0, 1.0)


#: frames of a long take the blend's bands are worked out on at once (with the frames either
#: side that they read): their several take-sized arrays at once were most of the peak memory
#: on a 30-minute 120 Hz take
BLEND_PIECE = 16384


def keep_unexplained(
    residual: np.ndarray,
    noise_var: np.ndarray,
    spikes: np.ndarray,
    fps: float,
    fast_margin: float | None = FAST_MARGIN,
    missing: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """What of the input's difference from the denoiser's output to keep: the part its noise
    does not explain, band by band (a slow band, where the denoiser's own errors sit, and a
    fast one, where white noise sits), and nothing at the input's spikes nor where it has no
    value. A long take goes :data:`BLEND_PIECE` frames at a time, each with the frames either
    side that its bands and shares read (the same values as the take at once, to rounding).

    residual: (T, C, 3) input minus output; noise_var: (C,); spikes: (T, C) bool;
    fast_margin: how many times its noise variance the fast band must exceed before any of it
    is put back (:data:`FAST_MARGIN`; :data:`GONE_MARGIN` where only a failed output is to
    give way), None: none of it; missing: (T, C) bool or None -> (kept residual (T, C, 3),
    the slow band's kept share (T, C))"""
    T = residual.shape[0]
    # a frame's shares read its bands half a share width either side, and a band reads the
    # residual a kernel's radius further
    halo = len(gaussian_coefficients(BAND_SECONDS * fps)) // 2 + _blend_width(fps) // 2 + 1
    if T <= BLEND_PIECE + 2 * halo:
        return _keep_unexplained(residual, noise_var, spikes, fps, fast_margin, missing)
    kept, share = np.empty(residual.shape), np.empty(residual.shape[:2])
    for a in range(0, T, BLEND_PIECE):
        b = min(a + BLEND_PIECE, T)
        lo, hi = max(0, a - halo), min(T, b + halo)
        holes = None if missing is None else missing[lo:hi]
        part = _keep_unexplained(residual[lo:hi], noise_var, spikes[lo:hi], fps, fast_margin,
                                 holes)  # fmt: skip
        kept[a:b], share[a:b] = part[0][a - lo : b - lo], part[1][a - lo : b - lo]
    return kept, share


def _blend_width(fps: float) -> int:
    """Frames over which a band's kept share is read (odd, at least 3)."""
    return max(3, int(round(BLEND_SECONDS * fps)) | 1)


def _keep_unexplained(
    residual: np.ndarray,
    noise_var: np.ndarray,
    spikes: np.ndarray,
    fps: float,
    fast_margin: float | None,
    missing: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`keep_unexplained` on the frames given, at once."""
    r = np.where(spikes[..., None], 0.0, residual)
    kernel = gaussian_coefficients(BAND_SECONDS * fps)
    seen3 = None if missing is None else (~missing).astype(float)[..., None]
    if seen3 is not None:  # the input's values alone make the bands beside a hole
        r = r * seen3
    slow = _smooth_seen(r, kernel, seen3)
    fast = r - slow
    # white noise's variance in each band, per unit of input noise variance
    delta = np.zeros_like(kernel)
    delta[len(kernel) // 2] = 1.0
    width = _blend_width(fps)
    slow_noise = SLOW_MARGIN * noise_var * (kernel**2).sum()
    seen = None if missing is None else (~missing).astype(float)
    keep_slow = kept_share((slow**2).mean(-1), slow_noise, width, seen)
    if fast_margin is None:
        return keep_slow[..., None] * slow, keep_slow
    fast_noise = fast_margin * noise_var * ((delta - kernel) ** 2).sum()
    keep_fast = kept_share((fast**2).mean(-1), fast_noise, width, seen)
    return keep_slow[..., None] * slow + keep_fast[..., None] * fast, keep_slow


def _smooth_seen(r: np.ndarray, kernel: np.ndarray, seen3: np.ndarray | None) -> np.ndarray:
    """``smooth_in_time`` of r (T, C, 3) over the frames where ``seen3`` (T, C, 1) is 1 alone
    (no pull to zero beside a hole), zero where it is 0; all frames when None."""
    if seen3 is None:
        return smooth_in_time(r, kernel)
    return smooth_in_time(r, kernel) / np.maximum(smooth_in_time(seen3, kernel), 1e-6) * seen3


def blend_rotations(
    source: np.ndarray,
    denoised: np.ndarray,
    fps: float,
    fast: bool = True,
    missing: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each joint's denoised rotation with the part of the input's difference from it that
    the input's noise does not explain put back.

    source, denoised: (T, J, 3) axis-angle; missing: (T, J) bool, where the input has no
    value (taken from the denoiser, as at a spike), or None -> (blended (T, J, 3), the share
    of the slow difference put back (T, J): 0 = the denoiser's, 1 = the input's; spikes (T, J))
    """
    return _blend_rotations(source, denoised, fps, fast, missing)[:3]


def _blend_rotations(
    source: np.ndarray,
    denoised: np.ndarray,
    fps: float,
    fast: bool,
    missing: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """:func:`blend_rotations`, the source's unwrapped rotation vectors it read the noise
    from (T, J, 3), which the spikes' fill reads again, and whether the take reads as noisy
    (:func:`noisy_take`)."""
    src = torch.as_tensor(source, dtype=torch.float64)
    residual, unwrapped = np.empty(src.shape), np.empty(src.shape)
    before = None  # the chunk before's last frame: its rotation vector, its unwrapped quaternion
    for a in range(0, len(src), CACHE_FRAMES):  # per frame (the unwrap carried across)
        s, frames = src[a : a + CACHE_FRAMES], slice(a, a + CACHE_FRAMES)
        q_src = rotvec_to_quat(s)
        residual[frames] = rotvec_product(denoised[frames], source[frames], invert_a=True)
        n = len(s)
        if before is not None:  # start the sign-continuous quaternions where the last chunk ended
            s, q_src = torch.cat([before[0], s]), torch.cat([before[1], q_src])
        flipped = rotvec_unwrap(s, dim=0, quats=q_src)[-n:]
        unwrapped[frames] = flipped.numpy()
        # an unwrapped vector past half a turn gives the flipped quaternion (w < 0) back
        before = (s[-1:], rotvec_to_quat(flipped[-1:]))
    seen = None if missing is None else ~missing
    pooled = noise_variance(unwrapped, seen)  # (J,)
    noisy = noisy_take(pooled)
    # the noise of a joint whose noise sits on one axis (an AMC knee's one dof) is read there:
    # read at its still axes' level, a noisy knee's every tenth frame reads as a spike
    margin = NOISY_AXIS_MARGIN if noisy else ONE_AXIS_MARGIN
    noise = component_noise_variance(unwrapped, seen, pooled, margin)
    spikes = spike_frames(unwrapped, noise, SPIKE_FLOOR_RAD, fps)
    if missing is not None:
        spikes = spikes & ~missing
    # the residual's mean square over its components holds the noise's mean over them
    kept, share = keep_unexplained(residual, noise, spikes, fps, _fast_margin(fast), missing)
    # on a noisy take the root's fast band is the denoiser's: the local rotations below it were
    # made for the denoiser's root, and the input's fast turns (its noise, or motion the
    # denoiser's root lacks) turned the whole body with them (docs/model.md, "Do no harm")
    if noisy and fast:
        root = None if missing is None else missing[:, :1]
        kept[:, :1], share[:, :1] = keep_unexplained(residual[:, :1], noise[:1], spikes[:, :1],
                                                     fps, None, root)  # fmt: skip
    out = np.empty(src.shape)
    # the denoised quaternions are made again chunk by chunk rather than kept whole: on a long
    # take a whole array of them is a large share of the peak memory, and cheap to make
    for a in range(0, len(src), CACHE_FRAMES):
        frames = slice(a, a + CACHE_FRAMES)
        out[frames] = rotvec_product(denoised[frames], kept[frames])
    return out, share, spikes, unwrapped, noisy


def _fast_margin(fast: bool) -> float:
    """The fast band's margin of a blend with (``fast``) or without it: without it, the band
    still gives way where the denoiser's output failed (:data:`GONE_MARGIN`)."""
    return FAST_MARGIN if fast else GONE_MARGIN


def noise_level(source: Motion) -> float:
    """How noisy a take's rotations read (rad): the median over its joints of each one's
    white-noise standard deviation (:func:`noise_variance` of its unwrapped rotations, the
    frames it has alone), what :func:`noisy_take` compares with ``TAKE_NOISE_RAD``."""
    if source.num_frames < 4:
        return 0.0
    rot = torch.as_tensor(source.joint_rotations, dtype=torch.float64)
    pooled = noise_variance(rotvec_unwrap(rot, dim=0).numpy(), observed(source))
    return float(np.sqrt(np.median(pooled))) if len(pooled) else 0.0


def noisy_take(noise_var: np.ndarray) -> bool:
    """Whether a take reads as noisy: the median of its joints' noise variances (J,) over
    ``infer.fill.TAKE_NOISE_RAD`` squared (a clean take's is 0.0005-0.0084 rad)."""
    return bool(len(noise_var)) and float(np.median(noise_var)) > TAKE_NOISE_RAD**2


def blend_translation(
    source: np.ndarray,
    denoised: np.ndarray,
    fps: float,
    fast: bool = True,
    missing: np.ndarray | None = None,
    noisy: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The root translation, blended as :func:`blend_rotations` does.

    source, denoised: (T, 3); missing: (T,) bool or None; noisy: whether the take's rotations
    read as noisy (:func:`noisy_take`: its noise on one axis read at its share from
    :data:`TRANS_AXIS_MARGIN` times the pooled median) ->
    (blended (T, 3), slow share put back (T,), spikes (T,))"""
    seen = None if missing is None else ~missing[:, None]
    margin = TRANS_AXIS_MARGIN if noisy else ONE_AXIS_MARGIN
    noise = component_noise_variance(source[:, None, :], seen, margin=margin)  # (1,)
    spikes = spike_frames(source[:, None, :], noise, SPIKE_FLOOR_M, fps)
    kept, share = keep_unexplained(
        (source - denoised)[:, None, :], noise, spikes, fps, _fast_margin(fast),
        None if missing is None else missing[:, None],
    )  # fmt: skip
    return denoised + kept[:, 0], share[:, 0], spikes[:, 0]


def source_spikes(source: Motion, joints: list[int] | None = None) -> np.ndarray:
    """(T, 22) bool: the spikes of ``source`` by the blend's rule (:func:`spike_frames`), in
    the rotations of ``joints`` (all when None; the others False) and, in the pelvis's
    column, its translation's: observations the input does not have, which a later stage
    (the foot lock's reference) must not read as the take's own."""
    J = source.joint_rotations.shape[1]
    cols = list(range(J)) if joints is None else list(joints)
    out = np.zeros((source.num_frames, J), bool)
    if source.num_frames < 4:
        return out
    seen = observed(source)
    rot = torch.as_tensor(source.joint_rotations[:, cols], dtype=torch.float64)
    unwrapped = rotvec_unwrap(rot, dim=0).numpy()
    pooled = noise_variance(unwrapped, seen[:, cols])
    noise = component_noise_variance(unwrapped, seen[:, cols], pooled)
    out[:, cols] = spike_frames(unwrapped, noise, SPIKE_FLOOR_RAD, source.fps) & seen[:, cols]
    trans = np.asarray(source.trans, np.float64)[:, None, :]
    noise_t = noise_variance(trans, seen[:, :1])
    out[:, 0] |= spike_frames(trans, noise_t, SPIKE_FLOOR_M, source.fps)[:, 0] & seen[:, 0]
    return out


def blend_motion(source: Motion, denoised: Motion, fast: bool = True) -> tuple[Motion, BlendReport]:
    """``denoised`` (the denoiser's output at the source's frame times) with what the
    source's own noise does not explain put back (``fast``: the fast band too), and how much
    was. Where the source misses a joint (``joint_mask`` False) the denoiser's value stays;
    its spikes (rotations and translation) are filled as short holes
    (``infer.fill.fill_spikes``).

    -> (the blended motion: a copy of ``denoised`` with new body parameters, its report)"""
    if source.num_frames < 4:  # too short to tell noise from motion: the denoiser's
        return denoised, BlendReport(0.0, 0.0)
    rot_src = source.joint_rotations
    rot_den = denoised.joint_rotations
    missing = None if source.joint_mask is None else ~np.asarray(source.joint_mask, bool)
    rot, share, spikes, unwrapped, noisy = _blend_rotations(
        rot_src, rot_den, source.fps, fast, missing
    )
    trans, _, trans_spikes = blend_translation(
        np.asarray(source.trans, np.float64),
        np.asarray(denoised.trans, np.float64),
        source.fps,
        fast,
        None if missing is None else missing[:, 0],
        noisy,
    )
    dtype = denoised.pose_body.dtype
    out = denoised.with_body(
        root_orient=rot[:, 0].astype(dtype),
        pose_body=rot[:, 1:].astype(dtype),
        trans=trans.astype(denoised.trans.dtype),
    )
    if spikes.any() or trans_spikes.any():
        out = fill_spikes(source, out, spikes, trans_spikes, unwrapped)
    if spikes.any():  # the joints below a filled one where the input had them
        rot = keep_worlds_below_spikes(rot_src, rot_den, out.joint_rotations, spikes,
                                       None if missing is None else ~missing)  # fmt: skip
        out = out.with_body(root_orient=rot[:, 0].astype(dtype), pose_body=rot[:, 1:].astype(dtype))
    return out, BlendReport(float(share.mean()), float(spikes.any(axis=1).mean()))
