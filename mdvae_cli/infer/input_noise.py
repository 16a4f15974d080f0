"""A take's own noise, read from the take alone: the white-noise variance of each channel from
its third differences in time. White noise of variance s^2 gives third differences of variance
20 s^2, while a smooth motion's third differences are small at any rate of 24 Hz and up; the
median keeps fast moves from inflating it. Read by the blend (``infer.noise_blend``), the hole
fill (``infer.fill``) and the page's noise band (``view.page``).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

#: the median of a chi-square variable with one degree of freedom over its mean
CHI2_MEDIAN = 0.4549
#: the order of the differences the noise is read from (white noise of unit variance gives
#: differences of variance C(2n, n): 20 for the third)
NOISE_ORDER = 3


def noise_variance(values: np.ndarray, seen: np.ndarray | None = None) -> np.ndarray:
    """The white-noise variance of each channel from its third differences in time.

    values: (T, C, ...); seen: (T, C) bool, where the values are the input's own (a hole's
    placeholders are a straight line, no noise: differences that reach into one are left out),
    or None -> (C, ...) (per channel, the median over time and the remaining trailing axis
    when there is one per channel); zeros for T < 4 or a channel with no difference left."""
    if values.shape[0] < NOISE_ORDER + 1 or values.shape[1] == 0:
        return np.zeros(values.shape[1:-1] if values.ndim > 2 else values.shape[1:])
    ok = None
    if seen is not None:
        ok = np.ones((values.shape[0] - NOISE_ORDER, values.shape[1]), bool)
        for k in range(NOISE_ORDER + 1):
            ok &= seen[k : k + len(ok)]
    # a channel at a time: the same medians as over the whole array at once, without its
    # copies (three of the take's size: 340 MB a copy on a 30-minute 120 Hz take)
    return np.stack(
        [
            _channel_noise(values[:, c], None if ok is None else ok[:, c], values.ndim > 2)
            for c in range(values.shape[1])
        ]
    )


def _channel_noise(v: np.ndarray, ok: np.ndarray | None, pool: bool) -> np.ndarray:
    """One channel's noise variance.  v: (T, ...); ok: (T - 3,) bool, the differences read,
    or None; pool: the last axis holds one channel's components (pooled) -> (...) without the
    pooled axis"""
    d3 = np.diff(v, n=NOISE_ORDER, axis=0) ** 2
    if ok is not None:
        d3[~ok] = np.nan
    if pool:
        d3 = np.moveaxis(d3, -1, 0).reshape(-1, *v.shape[1:-1])
    scale = math.comb(2 * NOISE_ORDER, NOISE_ORDER) * CHI2_MEDIAN
    if ok is None:
        return np.median(d3, axis=0) / scale
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a channel never seen: 0, no warning
        med = np.nan_to_num(np.nanmedian(d3, axis=0)) if np.isfinite(d3).any() else d3[0] * 0
    return np.nan_to_num(med) / scale


#: the lag-1 correlation of white noise's third differences is -15/20; a component whose third
#: differences correlate below this is read as noise (a smooth motion's correlate near +1)
WHITE_CORRELATION = -0.5
#: ... and the white components' share is taken only where it is this many times the pooled
#: median (a hinge's noise reads far above its still axes; a clean take's own jitter does not)
ONE_AXIS_MARGIN = 10.0


def component_noise_variance(
    values: np.ndarray,
    seen: np.ndarray | None = None,
    pooled: np.ndarray | None = None,
    margin: float = ONE_AXIS_MARGIN,
) -> np.ndarray:
    """Each channel's noise variance, not read below the share of it that its components
    that are white noise hold: :func:`noise_variance`'s median over the pooled components
    reads a noise that sits on one axis alone (an AMC knee's one dof, a BVH joint with one
    moving channel) at the still axes' level; here each component whose third differences are
    white noise's (lag-1 correlation under :data:`WHITE_CORRELATION`) counts its own noise,
    a third of the channel's, where that is ``margin`` times the pooled median. A smooth or
    clean channel reads as before.

    values: (T, C, K); seen: (T, C) bool or None; pooled: :func:`noise_variance` of the same
    values, when the caller has it -> (C,)"""
    T, C, K = values.shape
    pooled = noise_variance(values, seen) if pooled is None else pooled
    if T < NOISE_ORDER + 3:
        return pooled
    flat = values.reshape(T, C * K)
    per = noise_variance(flat, None if seen is None else np.repeat(seen, K, axis=1))
    white = np.zeros(C * K, bool)
    for i in range(C * K):  # a component at a time: no copies of the take's size
        d3 = np.diff(flat[:, i], n=NOISE_ORDER)
        if seen is not None:
            ok = np.ones(len(d3), bool)
            for k in range(NOISE_ORDER + 1):
                ok &= seen[k : k + len(ok), i // K]
            d3 = np.where(ok, d3, 0.0)
        white[i] = np.dot(d3[1:], d3[:-1]) < WHITE_CORRELATION * max(np.dot(d3, d3), 1e-300)
    share = (np.where(white, per, 0.0).reshape(C, K)).sum(axis=-1) / K
    return np.where(share > margin * pooled, share, pooled)
