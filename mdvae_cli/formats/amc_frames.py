"""The frame numbers of an AMC take: each frame's place in time (``formats.asfamc``).

An AMC frame's number is its time (CMU numbers from 1, at 120 Hz). :func:`arrange_frames`
places the frames a file lists by their numbers:

* numbers missing inside the take (``48 49 60 61``: frames 50-59 lost) are frames the file
  lacks: rows are added for them (``FramePlan.added``), so that the motion keeps its timing,
  and they are holes of the motion (``retarget.take.with_missing`` marks them in
  ``joint_mask``; ``denoise`` fills them, ``--fill off`` writes the file's own frames alone);
* numbers out of order are taken in the order of their numbers (a note says where);
* a number listed twice is refused, in one line naming the number and both lines;
* a take whose first number is not 1 keeps its numbering; numbers spanning far more frames
  than the file holds (``1 2 3 900000``) are refused, as for a video track's frame ids;
* numbers that step by k > 1 throughout (``1 3 5 7``: every 2nd frame of a capture kept) are
  consecutive frames, not holes (``FramePlan.step``; the reader takes the rate as 1/k of the
  assumed one).

A last frame the reader dropped (cut off mid-way) takes no part: it stays last, to be written
back as it was.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from mdvae_cli.errors import InputError


@dataclass
class FramePlan:
    """Where each frame of an AMC file goes.  R rows (the file's frames in the order of their
    numbers, a row added for each missing number, then a cut-off last frame).

    source: (R,) int, the file frame (in file order) of each row, -1 for an added one.
    numbers: (R,) the frame numbers as written (an added row's as ``str``). added: (R,) bool,
    True for a frame the file lacks. T: the rows a motion holds (all but a cut-off frame).
    notes: what the user is told (frames sorted, frames missing). step: the step of numbers
    that step by more than 1 throughout (every k-th frame of a capture), else 1.
    """

    source: np.ndarray
    numbers: list[str]
    added: np.ndarray
    T: int
    notes: list[str] = field(default_factory=list)
    step: int = 1

    @property
    def changed(self) -> bool:
        """Whether the rows differ from the file's frames in file order."""
        in_order = np.array_equal(self.source, np.arange(len(self.source)))
        return bool(self.added.any()) or not in_order


def arrange_frames(
    numbers: list[str], complete: int, path: str, line_of: Callable[[int], str]
) -> FramePlan:
    """The :class:`FramePlan` of a file whose frames are numbered ``numbers`` (F,) (digits),
    the first ``complete`` of them whole. line_of: file frame -> where its number is written
    ("line 12"), for the messages. InputError for a number listed twice, or numbers spanning
    far more frames than the file holds."""
    F = len(numbers)
    big = next((i for i in range(complete) if len(numbers[i].lstrip("0")) > 15), None)
    if big is not None:  # int() of a long one is slow, or refused past 4,300 digits
        shown = numbers[big] if len(numbers[big]) <= 20 else numbers[big][:20] + "..."
        raise InputError(f"{path}: frame number {shown} ({line_of(big)}) is too large to be a "
                         "frame's")  # fmt: skip
    ints = [int(n) for n in numbers[:complete]]
    order = sorted(range(complete), key=ints.__getitem__)
    for a, b in zip(order, order[1:], strict=False):
        if ints[a] == ints[b]:
            first, second = sorted((a, b))
            raise InputError(f"{path}: frame number {numbers[second]} is listed twice "
                             f"({line_of(first)} and {line_of(second)}); a take lists each "
                             "frame once")  # fmt: skip
    notes = []
    down = next((i for i in range(1, complete) if ints[i] < ints[i - 1]), None)
    if down is not None:
        notes.append(f"frame numbers out of order ({line_of(down)}: {numbers[down]} after "
                     f"{numbers[down - 1]}): the frames are taken in the order of their "
                     "numbers")  # fmt: skip
    if complete == 0:
        return FramePlan(np.arange(F), list(numbers), np.zeros(F, bool), 0, notes)
    low, high = ints[order[0]], ints[order[-1]]
    step = even_step([ints[i] for i in order])
    if step > 1:  # every k-th frame of a capture: consecutive frames, not holes
        rows = np.array(order + list(range(complete, F)), dtype=np.int64)
        return FramePlan(rows, [numbers[i] for i in rows], np.zeros(F, bool), complete, notes,
                         step)  # fmt: skip
    span = high - low + 1
    if span > 20 * complete + 1000:  # checked before any row is made
        raise InputError(
            f"{path}: frame numbers {numbers[order[0]]}..{numbers[order[-1]]} for {complete} "
            "frames; the numbers are not one take's frames"
        )
    source = np.full(span, -1, dtype=np.int64)
    source[[ints[i] - low for i in order]] = order
    added = source < 0
    rows = [numbers[i] if i >= 0 else str(low + r) for r, i in enumerate(source)]
    if added.any():
        notes.append(describe_gaps(low, added))
    cut = np.arange(complete, F)  # a cut-off last frame stays last
    return FramePlan(np.concatenate([source, cut]), rows + [numbers[i] for i in cut],
                     np.concatenate([added, np.zeros(len(cut), bool)]), span, notes)  # fmt: skip


def even_step(ints: list[int]) -> int:
    """The step of sorted frame numbers (F,) that step by one k > 1 throughout (three frames
    at least, ``1 3 5``), else 1."""
    steps = set(np.diff(ints).tolist())
    return steps.pop() if len(ints) >= 3 and len(steps) == 1 and min(steps) > 1 else 1


def describe_gaps(first: int, added: np.ndarray) -> str:
    """The note for the frames missing from a take numbered from ``first``; added: (R,) bool."""
    edges = np.diff(np.concatenate([[0], added.astype(np.int8), [0]]))
    runs = list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))
    names = [f"{first + a}" if b - a == 1 else f"{first + a}-{first + b - 1}" for a, b in runs]
    listed = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    return (f"frame numbers {listed} missing ({int(added.sum())} frame(s) in {len(runs)} "
            "gap(s)): read as holes at their times")  # fmt: skip


def apply_plan(
    plan: FramePlan,
    values: dict[str, np.ndarray],
    tokens: dict[str, np.ndarray],
    bones: list[tuple[str, ...]],
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], list[tuple[str, ...]]]:
    """The file's frames as ``plan`` places them.

    values: bone -> (F, n) as read; tokens: bone -> (F, n) the values as written (None where
    a frame left the bone out); bones: (F,) the bones each frame lists. Returns the same for
    the R rows: a bone a row leaves out holds the row before's value; an added row lists the
    bones of the row before (then those only the frame after it lists), its values
    interpolated linearly (per channel, by frame number) between the frames either side and
    its tokens "" (no text yet: written from the values).
    """
    src, added, T = plan.source, plan.added, plan.T
    have = np.flatnonzero(~added[:T])  # rows of the whole frames
    gaps = np.flatnonzero(added[:T])
    out_v, out_t = {}, {}
    for bone, v in values.items():
        tok = tokens[bone][np.maximum(src, 0)]
        val = np.array(v[np.maximum(src, 0)], dtype=np.float64)
        if tok.shape[1]:  # left out of a row: the value of the row before that lists it
            keep = np.where((tok[:T, 0] != None) & ~added[:T], np.arange(T), 0)  # noqa: E711
            val[:T] = val[np.maximum.accumulate(keep)]
        for c in range(val.shape[1] if len(gaps) else 0):
            val[gaps, c] = np.interp(gaps, have, val[have, c])
        tok[added] = None
        out_v[bone], out_t[bone] = val, tok
    order: list[tuple[str, ...]] = []
    for r, i in enumerate(src):
        if i >= 0:
            order.append(bones[i])
        else:  # the bones of the frame before, then those only the frame after lists
            after = bones[src[r + np.argmax(src[r:] >= 0)]]
            order.append(order[r - 1] + tuple(b for b in after if b not in order[r - 1]))
    for r in np.flatnonzero(added):
        for bone in order[r]:
            out_t[bone][r] = ""
    return out_v, out_t, order
