"""Holes in a BVH or ASF/AMC take (``--missing``): frames and joints a rule names as missing.

These formats have no way to say "not observed": an exporter writes *something* in every
channel. Two patterns mean a hole, and each is a rule:

* ``frozen``: every channel of a joint stays exactly the same (as written) for at least
  :func:`frozen_frames` frames (1/3 s, at least 5 frames) while other joints move, and then
  jumps: its change into the next frame is over JUMP (3) times the 90th percentile of its
  frame-to-frame changes in the take. That is a solver that lost a marker, held the last
  value, and caught up when the marker came back. The first frame of the stretch is the last
  one observed and the frames after it are missing (a stretch from the take's first frame,
  a joint not found yet, is missing from that frame on). Not holes: a joint that never moves in the
  take (an unanimated finger), a hold that eases out (a keyframed pose, a slow joint written
  with few decimals: the next change is one of its usual ones), a hold that runs to the end
  of the take (nothing shows it was lost). On the ten real BVH files of the test data it
  marks nothing; on 116 CMU takes (154,316 frames) it marks eight stretches in six takes,
  joints held (most at exactly 0) for 0.3-0.8 s, then jumping by 3-86 degrees: dropouts (the
  whole upper body at 0 for the first 0.4 s of 03_02, a neck frozen mid-take in 01_02), and
  a knee held straight at 0 in 105_08 (a 3.5 degree jump) that may be the solver's limit.
* ``zeros``: a frame in which every channel is exactly 0 (an exporter's empty frame, which the
  BVH reader already drops at the start and end of a take): the whole frame is missing.

:func:`missing_channels` applies the rules to a :class:`SourceMotion` read with its file layout
and gives a (T, J) mask over the take's own joints; ``retarget.take`` carries it onto the body,
with the frames an AMC file lacks (:func:`file_gaps`, missing whatever the rules).
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.source import SourceMotion

RULES = ("frozen", "zeros")
#: a frozen joint comes back with a jump: a change into the next frame over this many times
#: the 90th percentile of its frame-to-frame changes in the take
JUMP = 3.0


def parse_rules(text: str | None) -> tuple[str, ...]:
    """``"frozen,zeros"`` -> ("frozen", "zeros"); "" / None / "none" -> (); InputError for an
    unknown rule."""
    if not text or text.strip().lower() == "none":
        return ()
    rules = tuple(dict.fromkeys(r.strip().lower() for r in text.split(",") if r.strip()))
    unknown = [r for r in rules if r not in RULES]
    if unknown:
        raise InputError(f"--missing: unknown rule {unknown[0]!r}; give {', '.join(RULES)} "
                         "(comma-separated) or none")  # fmt: skip
    return rules


def frozen_frames(fps: float) -> int:
    """Frames a joint must stay exactly still to count as frozen: 1/3 s, at least 5."""
    return max(5, round(fps / 3))


def channel_data(src: SourceMotion) -> tuple[np.ndarray, np.ndarray]:
    """The take's channel values as written, (T, C), one row per frame of ``src``, and the
    source joint of each column (C,); InputError when ``src`` holds no file layout."""
    layout = src.layout
    if hasattr(layout, "channels") and hasattr(layout, "data"):  # BVH
        data = np.asarray(layout.data)[layout.rows]
        return data, np.array([j for j, _, _ in layout.channels], dtype=int)
    if hasattr(layout, "values"):  # AMC
        index = {name: j for j, name in enumerate(src.names)}
        blocks, owners = [], []
        for bone, values in layout.values.items():
            if bone in index and values.shape[1]:
                blocks.append(np.asarray(values)[layout.rows])
                owners += [index[bone]] * values.shape[1]
        return np.concatenate(blocks, axis=1), np.array(owners, dtype=int)
    raise InputError("--missing applies to BVH and AMC takes read from their files")


def file_gaps(src: SourceMotion) -> np.ndarray | None:
    """(T,) bool, True for the frames of ``src`` its file lacks (an AMC take's missing frame
    numbers, ``formats.amc_frames``: holes whatever the rules); None when it lacks none."""
    gaps = getattr(src.layout, "gaps", None)
    if gaps is None:
        return None
    found = np.asarray(gaps(), bool)
    return found if found.any() else None


def missing_channels(src: SourceMotion, rules: tuple[str, ...]) -> tuple[np.ndarray, dict]:
    """(T, J) bool, True where ``rules`` name a source joint missing, and what was found:
    {"zero_frames": n, "frozen": {joint name: frames}}."""
    data, owner = channel_data(src)
    T, J = data.shape[0], src.num_joints
    frozen = np.zeros((T, J), bool)
    blank = ~np.any(data != 0.0, axis=1)
    if "frozen" in rules and T > 1:
        joints = np.unique(owner)
        still = np.stack(
            [np.all(data[1:, owner == j] == data[:-1, owner == j], axis=1) for j in joints], 1
        )  # (T - 1, joints with channels): frame t + 1 equals frame t
        still[blank[1:] | blank[:-1]] = True  # an empty frame is no motion of anyone
        need = frozen_frames(src.fps) - 1  # still steps in a row
        for k, j in enumerate(joints):
            if still[:, k].all():
                continue  # never moves in this take: not a hole
            step = np.abs(np.diff(data[:, owner == j], axis=0)).max(axis=1)  # (T - 1,)
            jump = JUMP * np.percentile(step[step > 0], 90)
            others = ~np.delete(still, k, axis=1).all(axis=1)  # (T - 1,) another joint moved
            for a, b in _runs(still[:, k]):
                if b - a >= need and b < T - 1 and step[b] > jump and others[a:b].any():
                    frozen[a + (a > 0) : b + 1, j] = True  # frame a: the last one observed
        frozen[blank] = False
    zeros = blank if "zeros" in rules else np.zeros(T, bool)
    found = {
        "zero_frames": int(zeros.sum()),
        "frozen": {src.names[j]: int(frozen[:, j].sum()) for j in np.flatnonzero(frozen.any(0))},
    }
    return frozen | zeros[:, None], found


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a (N,) bool array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def describe(found: dict, frames: int) -> str:
    """The note a take's ``--missing`` holes get."""
    parts = []
    if found["zero_frames"]:
        parts.append(f"{found['zero_frames']} all-zero frame(s)")
    frozen = found["frozen"]
    if frozen:
        names = ", ".join(list(frozen)[:3]) + (f" and {len(frozen) - 3} more" if len(frozen) > 3
                                               else "")  # fmt: skip
        parts.append(f"frozen channels of {names}")
    return f"--missing: {frames} frame(s) with missing joints ({'; '.join(parts)}) marked missing"
