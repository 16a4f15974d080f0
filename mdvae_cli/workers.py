"""A long take's chunks of frames worked on side by side.

The stages that go a chunk of frames at a time (the BVH pose solve, the way back to a take's
own skeleton) spend their time in large numpy and torch operations, which let go of Python's
lock while they run; threads then keep every core the process may use busy on independent
chunks. Results come back in the chunks' order, with at most one chunk per worker in flight
beyond the one being used, so memory stays flat in the take's length.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sized
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import torch

A = TypeVar("A")
B = TypeVar("B")


def _libc_trim():
    """glibc's ``malloc_trim``, or None elsewhere."""
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


_TRIM = _libc_trim()

#: seconds between two hand-backs of memory at the most
TRIM_SECONDS = 0.25

#: when memory was last handed back (``time.monotonic``); one value for the process, whose
#: heaps one trim goes through (two threads that race on it trim twice: harmless)
_last_trim = [float("-inf")]


def give_back_memory(every: float = TRIM_SECONDS) -> None:
    """Hand the memory freed by finished chunks back to the system: glibc keeps chunk-sized
    blocks for reuse in each thread's own heap (on a 30-minute 120 Hz BVH that held 140 MB
    more at the peak). At most every ``every`` seconds: each trim walks every heap, holds
    the allocator's locks while it does and lets the next chunk fault its pages in again
    (after every chunk, 0.4 s of a 10-minute 120 Hz BVH's 9.3 s). Nothing where the C
    library has no ``malloc_trim``."""
    now = time.monotonic()
    if _TRIM is not None and now - _last_trim[0] >= every:
        _last_trim[0] = now
        _TRIM(0)


def worker_count() -> int:
    """Threads for chunks of frames: torch's own thread count (the machine's cores unless
    ``OMP_NUM_THREADS`` or ``torch.set_num_threads`` says fewer)."""
    return max(1, torch.get_num_threads())


def map_in_order(
    fn: Callable[[A], B],
    items: Iterable[A],
    workers: int | None = None,
    stop: threading.Event | None = None,
) -> Iterator[B]:
    """``fn`` over ``items`` on ``workers`` threads (None: :func:`worker_count`), results in
    the items' order. An exception in ``fn`` is raised where its result would come. While
    the threads run, torch works one thread per call (each thread is already one core's
    worth), and its thread count is restored after. A sized ``items`` of at most one (a
    short take's one chunk) is worked on in place: no threads, no hand-back of memory.

    The threads still running when the consumer leaves (an error, Ctrl-C, a ``break``) are
    waited for. ``stop`` is set first: a long ``fn`` that looks at it now and then can end
    there instead of running its course (``infer.progress.stoppable``)."""
    if isinstance(items, Sized) and len(items) <= 1:
        yield from (fn(item) for item in items)
        return
    workers = worker_count() if workers is None else workers
    items = iter(items)
    give_back_memory(0.0)  # what the stage before let go of: before this one's chunks
    if workers <= 1:
        for item in items:
            result = fn(item)
            give_back_memory()
            yield result
        return
    threads = torch.get_num_threads()
    pool = ThreadPoolExecutor(workers)
    pending: deque[Future] = deque()
    torch.set_num_threads(1)
    try:
        for item in items:
            pending.append(pool.submit(fn, item))
            if len(pending) > workers:
                yield _taken(pending.popleft())
        while pending:
            yield _taken(pending.popleft())
    finally:  # a failure or a consumer that stops early: no chunk left running
        if stop is not None:
            stop.set()
        pool.shutdown(wait=True, cancel_futures=True)
        torch.set_num_threads(threads)


def _taken(future: Future):
    """A chunk's result, its working memory given back."""
    result = future.result()
    give_back_memory()
    return result
