"""Contact runs over time, vectorised: which frames of a (T, K) bool array are held, cleaned,
faded and pulled to a goal, for foot locking (:mod:`mdvae_cli.infer.feet`).

Every function works on whole arrays: a frame finds the last and the next contact frame
(:func:`last_true`, :func:`next_true`: a running maximum or minimum of indices), and a run's
length, mean or end correction follows from those, so no Python loop runs over frames or runs
(a 72,000-frame take has thousands of runs).
"""

from __future__ import annotations

import numpy as np


def contact_runs(contact: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in a (T,) bool array, as [start, stop) pairs in order."""
    c = np.concatenate([[False], np.asarray(contact, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(c.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def last_true(c: np.ndarray) -> np.ndarray:
    """For each frame, the last frame at or before it where ``c`` is True (-1 if none), each
    column on its own.  (T, K) bool -> (T, K) int"""
    t = np.arange(len(c))[:, None]
    return np.maximum.accumulate(np.where(c, t, -1), axis=0)


def next_true(c: np.ndarray) -> np.ndarray:
    """For each frame, the first frame at or after it where ``c`` is True (T if none), each
    column on its own.  (T, K) bool -> (T, K) int"""
    T = len(c)
    t = np.arange(T)[:, None]
    return np.minimum.accumulate(np.where(c, t, T)[::-1], axis=0)[::-1]


def clean_contacts(contacts: np.ndarray, min_frames: int, max_gap: int, extend: int) -> np.ndarray:
    """Fill gaps of up to ``max_gap`` frames between two contacts, drop contacts shorter than
    ``min_frames``, then extend the others by ``extend`` frames at both ends; each column on its
    own, with no loop over frames or runs.  (T, K) bool -> (T, K) bool"""
    c = np.array(contacts, dtype=bool)
    T = len(c)
    t = np.arange(T)[:, None]
    before, after = last_true(c), next_true(c)
    c |= (before >= 0) & (after < T) & (after - before - 1 <= max_gap)
    run = next_true(~c) - last_true(~c) - 1  # in a run: its length
    c &= run >= min_frames
    before, after = last_true(c), next_true(c)
    return ((before >= 0) & (t - before <= extend)) | ((after < T) & (after - t <= extend))


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def fade_weights(contacts: np.ndarray, blend: int) -> np.ndarray:
    """How much of each contact's correction a frame gets.  (T, K) bool -> (T, K, 2)

    [..., 0]: of the last run that ended before the frame, [..., 1]: of the next one to start
    after it; both 1 inside a run. Out of contact, each falls from 1 next to its run to 0 at
    ``blend + 1`` frames away (smoothstep); where two runs are that close, they share the frame
    (weights normalised to sum 1).
    """
    c = np.asarray(contacts, dtype=bool)
    T = len(c)
    t = np.arange(T)[:, None]
    before, after = last_true(c), next_true(c)
    w = np.stack(
        [
            np.where(before >= 0, _smoothstep(1 - (t - before) / (blend + 1)), 0.0),
            np.where(after < T, _smoothstep(1 - (after - t) / (blend + 1)), 0.0),
        ],
        axis=-1,
    )
    total = w.sum(-1, keepdims=True)
    share = ~c[..., None] & (total > 1)
    return np.where(share, w / np.maximum(total, 1e-12), w)


def run_means(values: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Each contact run's mean value, on the run's frames (``values`` elsewhere).
    values (T, K, D), contacts (T, K) bool -> (T, K, D)"""
    values = np.asarray(values, dtype=np.float64)
    c = np.asarray(contacts, dtype=bool)
    start, stop = last_true(~c) + 1, next_true(~c)  # in a run: its [start, stop)
    sums = np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, axis=0)])
    k = np.arange(c.shape[1])[None, :]
    mean = (sums[stop, k] - sums[start, k]) / np.maximum(stop - start, 1)[..., None]
    return np.where(c[..., None], mean, values)


def window_means(values: np.ndarray, contacts: np.ndarray, half: int) -> np.ndarray:
    """Each contact frame's mean value over the frames of its run at most ``half`` frames
    away (``values`` elsewhere): the run's mean where the run is no longer than ``half`` + 1.
    values (T, K, D), contacts (T, K) bool -> (T, K, D)"""
    values = np.asarray(values, dtype=np.float64)
    c = np.asarray(contacts, dtype=bool)
    t = np.arange(len(c))[:, None]
    lo = np.maximum(last_true(~c) + 1, t - half)
    hi = np.minimum(next_true(~c), t + half + 1)
    sums = np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, axis=0)])
    k = np.arange(c.shape[1])[None, :]
    mean = (sums[hi, k] - sums[lo, k]) / np.maximum(hi - lo, 1)[..., None]
    return np.where(c[..., None], mean, values)


def run_max(values: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Each contact run's largest value, on the run's frames (0 elsewhere).
    values (T, K), contacts (T, K) bool -> (T, K)"""
    c = np.asarray(contacts, dtype=bool)
    T, K = c.shape
    starts = c & ~np.concatenate([np.zeros((1, K), bool), c[:-1]])
    run = np.cumsum(starts, axis=0) - 1  # each frame's run, counted per column
    k = np.broadcast_to(np.arange(K)[None, :], (T, K))
    best = np.zeros((int(run.max(initial=0)) + 1, K))
    np.maximum.at(best, (run[c], k[c]), np.asarray(values, dtype=np.float64)[c])
    return np.where(c, best[np.maximum(run, 0), k], 0.0)


def stuck_path(path: np.ndarray, contacts: np.ndarray, stick: float) -> np.ndarray:
    """``path`` within each contact run moved only by the part of each frame's step over
    ``stick`` (m per frame; a static friction: a wander slower than that is no step), about
    the run's mean of ``path``. path (T, K, 2), contacts (T, K) bool -> (T, K, 2), ``path``
    out of contact"""
    c = np.asarray(contacts, dtype=bool)
    step = np.diff(np.asarray(path, dtype=np.float64), axis=0)
    size = np.linalg.norm(step, axis=-1, keepdims=True)
    inside = (c[1:] & c[:-1])[..., None]
    step = np.where(inside, step * np.maximum(0.0, 1 - stick / np.maximum(size, 1e-12)), 0.0)
    walked = np.concatenate([np.zeros((1, *step.shape[1:])), np.cumsum(step, axis=0)])
    return np.where(c[..., None], walked - run_means(walked, c) + run_means(path, c), path)


def travel_anchors(
    xy: np.ndarray,
    smooth: np.ndarray,
    contacts: np.ndarray,
    travel_tol: float,
    half: int,
    stick: float = 0.0,
) -> np.ndarray:
    """Where each held foot joint stays: its mean over its contact run, or, on a run over
    which its smoothed position strays more than ``travel_tol`` from that mean (a foot that
    travels on the floor: a shuffle, a slide, a pivot; a standing foot's denoised wander
    stays under it), its mean over the run's frames within ``half`` frames either side.
    With ``stick`` (m per frame) > 0, that mean is taken twice over ``half`` / 2 (a triangular
    window of the same reach) and moves only by its steps' part over ``stick``
    (:func:`stuck_path`): a travel is followed that much slower, a creep under it is held
    (a denoised standing foot's wander is slow).
    xy, smooth: (T, K, 2) the joints' horizontal positions, as they are and smoothed;
    contacts: (T, K) bool -> (T, K, 2)"""
    anchors = run_means(xy, contacts)
    stray = run_max(np.linalg.norm(smooth - run_means(smooth, contacts), axis=-1), contacts)
    travels = stray > travel_tol
    if not travels.any():
        return anchors
    if stick > 0:
        narrow = round(half / 2)
        tapered = window_means(window_means(xy, contacts, narrow), contacts, narrow)
        path = stuck_path(tapered, contacts, stick)
    else:
        path = window_means(xy, contacts, half)
    return np.where(travels[..., None], path, anchors)


def hold_targets(
    positions: np.ndarray,
    contacts: np.ndarray,
    goals: np.ndarray,
    weights: np.ndarray,
    pin: float = 0.0,
) -> np.ndarray:
    """Where each foot joint should be: on its goal in contact, fading back around it.

    positions: (T, K, 3) the joints as they are; contacts: (T, K) bool; goals: (T, K, 3) where
    they should be at the contact frames; weights: (T, K, 2) from :func:`fade_weights`.
    Out of contact, a frame moves by the correction (goal - position) at the end of the run
    before it and the start of the run after it, times their weights; ``pin`` (0 to 1) times
    the weight again of that horizontal move instead takes the joint toward the goal itself,
    so that next to a run the joint stays nearer where it was held and then catches up with
    the motion (a joint the motion lifts a frame early or puts down a frame late slides less
    there; the pin fading as the weight squared, the swing further out is hardly changed).
    -> (T, K, 3); equal to ``positions`` where ``weights`` are 0.
    """
    inside = np.asarray(contacts, dtype=bool)
    T = len(inside)
    shift = np.where(inside[..., None], goals - positions, 0.0)
    k = np.arange(inside.shape[1])[None, :]
    before, after = last_true(inside), next_true(inside)
    b, a = np.maximum(before, 0), np.minimum(after, T - 1)
    has = np.stack([before >= 0, after < T], axis=-1)[..., None]  # (T, K, 2, 1)
    ends = np.where(has, np.stack([shift[b, k], shift[a, k]], axis=-2), 0.0)
    move = ends  # the shift at the end of the run before, the start of the next
    if pin > 0:  # toward the goal there: by the distance from where the joint was there
        drift = np.stack([positions[b, k], positions[a, k]], axis=-2) - positions[:, :, None]
        drift = np.where(has, drift, 0.0) * np.array([1.0, 1.0, 0.0]) * weights[..., None]
        move = ends + pin * drift
    return positions + np.where(inside[..., None], shift, (weights[..., None] * move).sum(-2))
