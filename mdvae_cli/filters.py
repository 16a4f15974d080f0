"""Classical temporal filters a studio would try first: Gaussian and Savitzky-Golay smoothing,
and the One-Euro filter that video-mocap tools apply.

The first two are local polynomial least-squares smoothers applied along time, pure numpy:

* **Savitzky-Golay** (``window`` odd, ``order``): every frame takes the value at that frame of the
  polynomial of degree ``order`` fitted (unweighted least squares) to the ``window`` frames
  around it. At the ends the window does not shrink: it slides inward and stays the first (last)
  ``window`` frames, and the fitted polynomial is evaluated at the edge frame ("fit at the
  ends", the ``interp`` edge mode of common tools). A polynomial of degree <= ``order`` is
  therefore reproduced exactly at every frame, edges included. A motion shorter than the window
  is fitted by one polynomial over all its frames (degree capped at T - 1).
* **Gaussian** (``sigma_frames``): a Gaussian kernel truncated at 4 sigma. Away from the ends
  this is the plain normalised Gaussian convolution. Within 4 sigma of an end, the kernel is cut
  at the end and the frame takes the value of the Gaussian-weighted straight-line fit to the
  frames left under it. In the interior this is the same as plain convolution, because a
  symmetric kernel fits no slope. At the ends it keeps a constant-velocity drift instead of
  pulling the end frames towards the inside, which reflect- or nearest-padding would do.
* **One-Euro** (Casiez, Roussel, Vogel, CHI 2012; ``min_cutoff`` Hz, ``beta``, ``d_cutoff`` Hz):
  a causal first-order low-pass whose cutoff rises with the signal's speed, per component:
  ``cutoff = min_cutoff + beta * |dx/dt|`` (the speed itself low-passed at ``d_cutoff``), so
  slow motion is smoothed hard and fast motion lags little. It runs forward only, as in the
  live tools (ROMP's ``--temporal_optimize``, MediaPipe), and its first frame is the input's.

Rotations are smoothed as quaternions: each joint's axis-angle track is converted to unit
quaternions, made sign-continuous over time (each quaternion flipped into the hemisphere of its
predecessor, so q and -q, which are the same rotation, never alternate), and the 4 components
are filtered like any signal, renormalised and converted back. Each output frame keeps the
axis-angle branch of its input frame (angles in [0, 2*pi)). For example, a track unwrapped past
pi stays unwrapped, and a track in the usual [0, pi] convention stays in that convention.
Translation is filtered directly. Hands, face, betas and extra keys are left untouched.
Parameters are in frames, whatever the motion's frame rate.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.geometry.rotations_np import quat_continuous, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.motion.motion import Motion

#: The Gaussian kernel is cut at this many standard deviations.
GAUSSIAN_TRUNCATE = 4.0

Weights = Callable[[np.ndarray], np.ndarray]


# --------------------------------------------------------------------------------------------
# local polynomial fits


def local_poly_coefficients(
    positions: np.ndarray, order: int, at: float = 0.0, weights: np.ndarray | None = None
) -> np.ndarray:
    """Linear weights c such that ``c @ y`` is the fitted polynomial's value at ``at``.

    The polynomial of degree ``order`` is the weighted least-squares fit to the samples ``y``
    taken at ``positions``.  positions: (n,), weights: (n,) >= 0 or None (all 1) -> c: (n,)
    The degree is capped at n - 1. The weights sum to 1 (a constant is reproduced).
    """
    u = np.asarray(positions, dtype=np.float64) - float(at)
    n = u.shape[0]
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    scale = max(float(np.abs(u).max()), 1.0)  # conditioning: offsets in [-1, 1]
    A = np.vander(u / scale, min(order, n - 1) + 1, increasing=True)  # (n, p + 1)
    sw = np.sqrt(w)
    return np.linalg.pinv(A * sw[:, None])[0] * sw


@functools.lru_cache(maxsize=512)
def _edge_coefficients(n: int, order: int, at: int, weight_bytes: bytes) -> np.ndarray:
    """:func:`local_poly_coefficients` at frames 0..n-1 (a fit is shift-invariant, so a
    frame's row depends only on these), cached: every clip of a batch shares its rows."""
    c = local_poly_coefficients(np.arange(n), order, at, np.frombuffer(weight_bytes))
    c.flags.writeable = False
    return c


def savgol_coefficients(window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing weights for the centre frame.  -> (window,)

    ``c @ y[t - h : t + h + 1]`` (h = window // 2) is the smoothed value at frame t.
    """
    _check_savgol(window, order)
    h = window // 2
    return local_poly_coefficients(np.arange(-h, h + 1), order)


def gaussian_coefficients(sigma_frames: float) -> np.ndarray:
    """Normalised Gaussian kernel, truncated at 4 sigma.  -> (2r + 1,), r = ceil(4 sigma)"""
    _check_sigma(sigma_frames)
    r = _gaussian_radius(sigma_frames)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_frames) ** 2)
    return k / k.sum()


#: frames worked on at once by the smoothers here and the blend's steps (``infer.noise_blend``):
#: a long take's arrays (hundreds of MB at 120 Hz) streamed through memory once per operation
#: cost several times what the same work on pieces that stay in cache does
CACHE_FRAMES = 4096


def correlate_frames(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Each frame's weighted sum of the ``len(kernel)`` frames from it on, along axis 0, where
    they all exist ("valid" correlation).  x: (T, ...); kernel: (W,) -> (T - W + 1, ...)

    Each channel's frames go through numpy's compiled one-dimensional convolution,
    :data:`CACHE_FRAMES` frames at a time (their transposed copy stays in cache): a shifted
    multiply-add over the whole array per tap reads it ``W`` times from memory, 2.5-7x slower
    on a long take."""
    x = np.asarray(x, dtype=np.float64)
    W, T = len(kernel), x.shape[0]
    n = max(T - W + 1, 0)
    flat = x.reshape(T, math.prod(x.shape[1:]))
    out = np.empty((n, flat.shape[1]))
    taps = np.asarray(kernel, dtype=np.float64)[::-1]  # convolution flips the kernel back
    for a in range(0, n, CACHE_FRAMES):
        m = min(CACHE_FRAMES, n - a)
        block = flat[a : a + m + W - 1].T.copy()
        rows = np.empty((flat.shape[1], m))
        for c, channel in enumerate(block):
            rows[c] = np.convolve(channel, taps, "valid")
        out[a : a + m] = rows.T
    return out.reshape(n, *x.shape[1:])


def _smooth_local_poly(
    x: np.ndarray, half: int, order: int, weight: Weights, slide: bool, at: np.ndarray | None = None
) -> np.ndarray:
    """Smooth along axis 0 with local polynomial fits.  x: (T, ...) -> (T, ...), or only the
    frames ``at`` (sorted frame indices, (n,)) -> (n, ...): the rows of the whole result there.

    Frames whose centred window of 2*half + 1 frames fits inside the clip use one shared
    coefficient row, applied as a convolution. The first and last ``half`` frames get their
    own row: a window slid inward (``slide``) or cut at the end, with ``weight(offsets)``.
    """
    x = np.asarray(x, dtype=np.float64)
    T = x.shape[0]
    frames = np.arange(T) if at is None else np.asarray(at, dtype=np.int64)
    if T == 0 or half == 0:
        return x[frames].copy() if at is not None else x.copy()
    W = 2 * half + 1
    out = np.empty((len(frames), *x.shape[1:]))
    inner = (frames >= half) & (frames < T - half)
    if inner.any():
        offsets = np.arange(-half, half + 1)
        w = np.asarray(weight(offsets), dtype=np.float64)
        c = _edge_coefficients(W, order, half, w.tobytes())  # the centre row, cached too
        if at is None:  # every frame: one correlation with the centre row
            out[half : T - half] = correlate_frames(x, c)
        else:
            centre = frames[inner]
            rows = c[0] * x[centre - half]
            term = np.empty_like(rows)
            for k in range(1, W):
                rows += np.multiply(x[centre - half + k], c[k], out=term)
            out[inner] = rows
    for i in np.flatnonzero(~inner):
        t = int(frames[i])
        if slide:
            lo = min(max(t - half, 0), max(T - W, 0))
            hi = min(lo + W, T)
        else:
            lo, hi = max(t - half, 0), min(t + half + 1, T)
        idx = np.arange(lo, hi)
        w = np.asarray(weight(idx - t), dtype=np.float64)
        c = _edge_coefficients(hi - lo, order, t - lo, w.tobytes())
        out[i] = np.tensordot(c, x[lo:hi], axes=1)
    return out


def savgol_smooth(x: np.ndarray, window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing along axis 0 (fit at the ends).  x: (T, ...) -> (T, ...)

    window: odd number of frames >= 1; order: polynomial degree, 0 <= order < window.
    """
    _check_savgol(window, order)
    return _smooth_local_poly(x, window // 2, order, np.ones_like, slide=True)


def gaussian_smooth(x: np.ndarray, sigma_frames: float, at: np.ndarray | None = None) -> np.ndarray:
    """Gaussian smoothing along axis 0 (linear fit at the ends).  x: (T, ...) -> (T, ...);
    at: sorted frame indices (n,) -> only those rows, (n, ...)

    sigma_frames: standard deviation in frames, >= 0 (0 returns a copy).
    """
    _check_sigma(sigma_frames)
    if sigma_frames == 0:
        x = np.asarray(x, dtype=np.float64)
        return x.copy() if at is None else x[np.asarray(at, dtype=np.int64)]
    return _smooth_local_poly(
        x,
        _gaussian_radius(sigma_frames),
        1,
        lambda d: np.exp(-0.5 * (d / sigma_frames) ** 2),
        slide=False,
        at=at,
    )


def one_euro_smooth(
    x: np.ndarray, fps: float, min_cutoff: float, beta: float, d_cutoff: float = 1.0
) -> np.ndarray:
    """One-Euro filter along axis 0 (causal), each component on its own.
    x: (T, ...) -> (T, ...); fps: frames per second; cutoffs in Hz (> 0), beta >= 0."""
    _check_one_euro(min_cutoff, beta, d_cutoff)
    x = np.asarray(x, dtype=np.float64)
    out = np.empty_like(x)
    if x.shape[0] == 0:
        return out

    def alpha(cutoff):  # the smoothing factor of a first-order low-pass at ``cutoff`` Hz
        return 1.0 / (1.0 + fps / (2.0 * np.pi * cutoff))

    a_d = alpha(d_cutoff)
    out[0] = x[0]
    speed = np.zeros_like(x[0])
    for t in range(1, x.shape[0]):
        speed = speed + a_d * ((x[t] - out[t - 1]) * fps - speed)
        a = alpha(min_cutoff + beta * np.abs(speed))
        out[t] = out[t - 1] + a * (x[t] - out[t - 1])
    return out


# --------------------------------------------------------------------------------------------
# rotations


def smooth_rotvecs(
    rotvec: np.ndarray, smooth: Callable[[np.ndarray], np.ndarray], at: np.ndarray | None = None
) -> np.ndarray:
    """Smooth axis-angle tracks over time as sign-continuous quaternions.

    rotvec: (T, ..., 3); smooth: a filter along axis 0, (T, D) -> (T, D), or, with ``at``
    (frame indices, (n,)), -> (n, D): the filtered rows at those frames alone. -> (T, ..., 3)
    or (n, ..., 3), each frame on its input frame's axis-angle branch (see the module
    docstring).
    """
    rotvec = np.asarray(rotvec, dtype=np.float64)
    T = rotvec.shape[0]
    q_in = rotvec_to_quat(rotvec)
    q = quat_continuous(q_in)
    q_hat = smooth(q.reshape(T, -1))
    if at is not None:
        at = np.asarray(at, dtype=np.int64)
        q_in, q = q_in[at], q[at]
    q_hat = q_hat.reshape(q.shape)
    norm = np.linalg.norm(q_hat, axis=-1, keepdims=True)
    q_hat = np.where(norm > 1e-6, q_hat / np.maximum(norm, 1e-12), q)  # degenerate: keep input
    q_hat = np.where(np.sum(q_hat * q_in, axis=-1, keepdims=True) < 0, -q_hat, q_hat)
    return quat_to_rotvec(q_hat, keep_branch=True)


# --------------------------------------------------------------------------------------------
# motions


def filter_motion(motion: Motion, smooth: Callable[[np.ndarray], np.ndarray]) -> Motion:
    """Apply a temporal filter ((T, D) -> (T, D)) to the body pose, root orientation (as
    quaternions) and translation of ``motion``; a new Motion, everything else unchanged."""
    return filter_motions([motion], smooth)[0]


def filter_motions(
    motions: Sequence[Motion], smooth: Callable[[np.ndarray], np.ndarray]
) -> list[Motion]:
    """:func:`filter_motion` on many motions, in one call per distinct length (the filter works
    along time, so equal-length motions are smoothed side by side): same results as one by one,
    far fewer small array operations for a batch of short clips."""
    out: list[Motion | None] = [None] * len(motions)
    by_len: dict[int, list[int]] = {}
    for i, m in enumerate(motions):
        by_len.setdefault(m.num_frames, []).append(i)
    for T, idx in by_len.items():
        rot = np.stack(
            [motions[i].joint_rotations for i in idx],
            axis=1,
        )  # (T, N, 22, 3)
        trans = np.stack([np.asarray(motions[i].trans, dtype=np.float64) for i in idx], axis=1)
        rot = smooth_rotvecs(rot, smooth)
        trans = smooth(trans.reshape(T, -1)).reshape(trans.shape)
        for k, i in enumerate(idx):
            out[i] = motions[i].with_body(
                root_orient=rot[:, k, 0].copy(),
                pose_body=rot[:, k, 1:].copy(),
                trans=trans[:, k].copy(),
            )
    return out  # type: ignore[return-value]


def gaussian_filter_motion(motion: Motion, sigma_frames: float) -> Motion:
    """Gaussian smoothing of body pose, root orientation and translation over time.

    sigma_frames: kernel standard deviation in frames (> 0; 0 returns an unchanged copy).
    Same T and fps; hands, betas and extras untouched. Raises InputError on a bad sigma.
    """
    _check_sigma(sigma_frames)
    return filter_motion(motion, lambda x: gaussian_smooth(x, sigma_frames))


def savgol_filter_motion(motion: Motion, window: int, order: int) -> Motion:
    """Savitzky-Golay smoothing of body pose, root orientation and translation over time.

    window: odd number of frames; order: polynomial degree, 0 <= order < window.
    Same T and fps; hands, betas and extras untouched. Raises InputError on bad parameters.
    """
    _check_savgol(window, order)
    return filter_motion(motion, lambda x: savgol_smooth(x, window, order))


def one_euro_filter_motion(
    motion: Motion, min_cutoff: float, beta: float, d_cutoff: float = 1.0
) -> Motion:
    """One-Euro filtering of body pose, root orientation (quaternions) and translation, at the
    motion's own frame rate. Same T and fps; hands, betas and extras untouched."""
    _check_one_euro(min_cutoff, beta, d_cutoff)
    fps = motion.fps
    return filter_motion(motion, lambda x: one_euro_smooth(x, fps, min_cutoff, beta, d_cutoff))


# --------------------------------------------------------------------------------------------
# validation


def _check_one_euro(min_cutoff: float, beta: float, d_cutoff: float) -> None:
    for name, value, low in (("min_cutoff", min_cutoff, 0.0), ("d_cutoff", d_cutoff, 0.0)):
        if not (math.isfinite(value) and value > low):
            raise InputError(f"One-Euro {name} must be a finite number of Hz > 0, got {value!r}")
    if not (math.isfinite(beta) and beta >= 0):
        raise InputError(f"One-Euro beta must be a finite number >= 0, got {beta!r}")


def _gaussian_radius(sigma_frames: float) -> int:
    return max(1, math.ceil(GAUSSIAN_TRUNCATE * sigma_frames))


def _check_sigma(sigma_frames: float) -> None:
    try:
        finite = math.isfinite(float(sigma_frames))
    except (TypeError, ValueError):
        finite = False
    if not finite:
        raise InputError(f"Gaussian sigma must be a finite number of frames, got {sigma_frames!r}")
    if sigma_frames < 0:
        raise InputError(f"Gaussian sigma must be >= 0 frames, got {sigma_frames:g}")


def _check_savgol(window: int, order: int) -> None:
    if not isinstance(window, int | np.integer) or window < 1 or window % 2 == 0:
        raise InputError(f"Savitzky-Golay window must be an odd number of frames, got {window!r}")
    if not isinstance(order, int | np.integer) or not 0 <= order < window:
        raise InputError(
            f"Savitzky-Golay order must be between 0 and window - 1 ({window - 1}), got {order!r}"
        )
