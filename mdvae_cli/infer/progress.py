"""A denoise run's progress, told through a ``progress(info: dict)`` callback: the stages
("optimize", "refine": steps) and the "denoise" stage's phases of the whole (the windows
denoised, stitched, blended, feet locked: a long take's progress inside it)."""

from __future__ import annotations

import threading
from collections.abc import Callable

Progress = Callable[[dict], None] | None

CORE_PHASES = 2  # the "denoise" stage's phases without the blend and the foot lock


def staged(progress: Progress, stage: str, offset: int, total: int) -> Progress:
    """A progress callback that labels its stage and counts steps over several runs."""
    if progress is None:
        return None

    def tell(info: dict) -> None:
        progress({**info, "stage": stage, "step": offset + info["step"], "steps": total})

    return tell


def phase(progress: Progress, name: str, step: int, steps: int) -> None:
    """Tell ``progress`` that the ``step``-th of ``steps`` phases of the whole is done."""
    if progress is not None:
        progress({"stage": "denoise", "step": step, "steps": steps, "phase": name})


def more_phases(progress: Progress, extra: int) -> Progress:
    """``progress`` for an inner run whose "denoise" phases are followed by ``extra`` more."""
    if progress is None:
        return None

    def tell(info: dict) -> None:
        if info["stage"] == "denoise":
            info = {**info, "steps": info["steps"] + extra}
        progress(info)

    return tell


def progress_of_runs(progress: Progress, k: int, runs: int, count: int) -> list[Progress]:
    """``progress`` for ``count`` runs of the same kind (a long take's pieces: the k-th to the
    (k + count - 1)-th of ``runs``), each step counted among all of theirs, the runs before
    the k-th done. They may go on at the same time, from any thread: each tells the steps
    all of them have done so far in its stage, so that a stage's count only rises."""
    if progress is None or runs == 1:
        return [progress] * count
    done: dict[str | None, list[int]] = {}
    lock = threading.Lock()

    def teller(i: int) -> Callable[[dict], None]:
        def tell(info: dict) -> None:
            steps = int(info["steps"])
            with lock:
                stage = done.setdefault(info.get("stage"), [0] * count)
                stage[i] = int(info["step"])
                progress({**info, "step": k * steps + sum(stage), "steps": runs * steps})

        return tell

    return [teller(i) for i in range(count)]


class Stopped(Exception):
    """A run side by side told to stop: nobody will read its result (``stoppable``)."""


def stoppable(progress: Progress, stop: threading.Event) -> Callable[[dict], None]:
    """``progress`` (or nothing) that first raises :class:`Stopped` once ``stop`` is set: a
    refinement going side by side (``workers.map_in_order(..., stop=stop)``) ends at its next
    step when the command is interrupted, instead of finishing its batch first (a minute and
    more of ``--refine`` steps on a long take, which Ctrl-C would wait for)."""

    def tell(info: dict) -> None:
        if stop.is_set():
            raise Stopped
        if progress is not None:
            progress(info)

    return tell
