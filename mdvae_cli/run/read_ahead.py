"""Read a file in a child process while this one loads what the command needs.

A command's first file is read before anything can be done with it, and loading torch and the
model takes about a second, all of it holding Python's lock (a thread could not share it). A
parser is Python too (a 10-minute 120 Hz BVH: half a second). So where the system can fork and
a second core is free, :meth:`ReadAhead.start` runs a reading call in a child process, forked
while this process has neither torch nor any thread, and :meth:`ReadAhead.call` hands its value
over (pickled through a pipe) to the one same call made later. Whatever goes wrong in the child
(a bad file, a crash) leaves nothing to hand over, and :meth:`~ReadAhead.call` reads the file
itself, so every message a bad file gets is the usual one. The standard library only:
importing this module loads nothing.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any


def can_fork() -> bool:
    """Whether a read can go ahead here: ``os.fork`` exists (not on Windows; on macOS system
    libraries refuse to run in a forked child), this process has no other thread and has not
    loaded torch yet (the loading is what the child's work overlaps), and two cores are free."""
    if not hasattr(os, "fork") or sys.platform == "darwin":
        return False
    if "torch" in sys.modules or threading.active_count() > 1:
        return False
    cores = (
        os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else range(os.cpu_count() or 1)
    )
    return len(cores) >= 2


class ReadAhead:
    """Calls, each ``fn(*args, **kwargs)``, run in child processes (one a call) from
    :meth:`start` on, for :meth:`call` to hand over."""

    def __init__(self) -> None:
        self.children: list[tuple[tuple, int, int]] = []  # (the call, its pid, its pipe)

    def __len__(self) -> int:
        return len(self.children)

    def start(self, fn: Callable[..., Any], *args, **kwargs) -> bool:
        """Fork a child that makes the call and sends back its value. False where
        :func:`can_fork` says no (the caller's later call is then just made)."""
        if not can_fork():
            return False
        r, w = os.pipe()
        try:
            pid = os.fork()
        except OSError:  # no memory or processes left for a child: read in this one
            os.close(r)
            os.close(w)
            return False
        if pid == 0:  # the child: never returns into the caller's code
            os.close(r)
            for _, _, fd in self.children:  # its siblings' pipes are not its own
                os.close(fd)
            try:
                quiet = os.open(os.devnull, os.O_WRONLY)  # what it would say, the parent says
                os.dup2(quiet, 1)
                os.dup2(quiet, 2)
                try:
                    sent: tuple = ("value", fn(*args, **kwargs))
                except BaseException:  # noqa: BLE001 - the parent reads it again, and says why
                    sent = ("failed", None)
                with os.fdopen(w, "wb") as pipe:
                    pickle.dump(sent, pipe, protocol=pickle.HIGHEST_PROTOCOL)
            finally:
                os._exit(0)
        os.close(w)
        self.children.append(((fn, args, kwargs), pid, r))
        return True

    def call(self, fn: Callable[..., Any], *args, **kwargs) -> Any:
        """``fn(*args, **kwargs)``: a child's value where one made this same call and it
        succeeded (that child is then done with), else the call made here (its error, if
        any, raised here)."""
        match = [c for c in self.children if _same(c[0], (fn, args, kwargs))]
        if not match:
            return fn(*args, **kwargs)
        child = match[0]
        self.children.remove(child)
        try:
            with os.fdopen(child[2], "rb") as pipe:
                kind, value = pickle.load(pipe)
        except Exception:  # noqa: BLE001 - a child killed half-way: read here instead
            kind, value = "failed", None
        _reap(child[1])
        return value if kind == "value" else fn(*args, **kwargs)

    def close(self) -> None:
        """End the children whose values were not taken (they may still be reading)."""
        while self.children:
            _, pid, fd = self.children.pop()
            os.close(fd)
            os.kill(pid, signal.SIGKILL)
            _reap(pid)


def _same(a: tuple, b: tuple) -> bool:
    """Whether two calls are one (arguments that cannot say, arrays, are not)."""
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


def _reap(pid: int) -> None:
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
