"""What every command shares: the console, error handling, common options, batch runs."""

from __future__ import annotations

import functools
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from mdvae_cli.errors import MdvaeError, NotAvailableError, stop_words

#: the one console for human-readable output, each message one line however narrow the
#: terminal or pipe (a log is read with grep); machine output (--json) goes to stdout directly
console = Console(stderr=True, highlight=False, soft_wrap=True)


class OutputPath(click.Path):
    """``-o``'s type: a path, refused when empty (``-o "$OUT"`` with the variable unset would
    otherwise write into the working folder)."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value.strip():
            self.fail("is empty: name an output file or folder", param, ctx)
        return super().convert(value, param, ctx)


def fail(message: str, code: int = 1, as_json: bool = False) -> None:
    """Print ``error: message`` (one line) and exit with ``code``; ``as_json`` (a ``--json``
    run, whose reader expects a JSON document on stdout): also ``{"ok": false, "error": ...,
    "exit_code": ...}`` on stdout."""
    line = " ".join(str(message).split())
    console.print(f"[bold red]error:[/] {escape(line)}", soft_wrap=True)
    if as_json:
        click.echo(json.dumps({"ok": False, "error": line, "exit_code": code}, indent=2))
    sys.exit(code)


def handle_errors(fn: Callable) -> Callable:
    """Turn library exceptions into one-line errors with a non-zero exit code.

    MdvaeError -> exit 1 (NotAvailableError -> exit 2); any other exception -> exit 1 with its
    type and message, unless MDVAE_DEBUG=1, which re-raises for a traceback. With ``--json``
    the error is also a JSON document on stdout (:func:`fail`).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        as_json = bool(kwargs.get("as_json"))
        try:
            return fn(*args, **kwargs)
        except NotAvailableError as exc:
            fail(str(exc), code=2, as_json=as_json)
        except MdvaeError as exc:
            fail(str(exc), as_json=as_json)
        except KeyboardInterrupt as exc:
            fail(*stop_words(exc), as_json=as_json)
        except (click.exceptions.Exit, click.ClickException, SystemExit):
            raise
        except OSError as exc:  # the file system's refusal (name too long, no permission...)
            if os.environ.get("MDVAE_DEBUG"):
                raise
            fail(os_error_words(exc), as_json=as_json)
        except Exception as exc:
            if os.environ.get("MDVAE_DEBUG"):
                raise
            fail(f"{type(exc).__name__}: {exc} (set MDVAE_DEBUG=1 for a traceback)",
                 as_json=as_json)  # fmt: skip

    return wrapper


def os_error_words(exc: OSError) -> str:
    """An OSError as one line in words: ``FILE: File name too long``."""
    why = exc.strerror or str(exc)
    return f"{exc.filename}: {why}" if exc.filename is not None else why


class Finite(click.ParamType):
    """A finite float (nan and inf refused) within optional bounds; ``open_low``: the lower
    bound itself is refused (e.g. a learning rate must be > 0)."""

    name = "number"

    def __init__(self, low: float | None = None, high: float | None = None, open_low: bool = False):
        self.low, self.high, self.open_low = low, high, open_low

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            x = value
        else:
            try:
                x = float(value)
            except (TypeError, ValueError):
                self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.low is not None and (x < self.low or (self.open_low and x == self.low)):
            self.fail(f"{x:g} is not {'>' if self.open_low else '>='} {self.low:g}", param, ctx)
        if self.high is not None and x > self.high:
            self.fail(f"{x:g} is not <= {self.high:g}", param, ctx)
        return x + 0.0  # -0.0 -> 0.0 (numpy refuses a noise scale of -0.0 as negative)


#: common shapes of numeric options
POSITIVE = Finite(0.0, open_low=True)
NON_NEGATIVE = Finite(0.0)
FRACTION = Finite(0.0, 1.0)
#: a random seed: 0..model.config.MAX_SEED, written out so that parsing options does not
#: import torch (a test checks the two agree)
SEED = click.IntRange(0, 2**63 - 1)


def body_model_option(fn: Callable) -> Callable:
    """``--body-model PATH``: an SMPL/SMPL-H/SMPL-X file; default the built-in body."""
    return click.option(
        "--body-model",
        "body_model",
        type=click.Path(path_type=Path),
        default=None,
        help="SMPL .pkl, SMPL-H or SMPL-X .npz body-model file (default: the built-in body).",
    )(fn)


def allow_pickle_option(fn: Callable) -> Callable:
    return click.option(
        "--allow-pickle",
        is_flag=True,
        help="Allow motion files that contain pickled Python objects (runs their code: only "
        "for files you trust).",
    )(fn)


def progress_bar(transient: bool = False) -> Progress:
    """A rich progress bar on the shared console (hidden when stderr is not a terminal)."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[info]}"),
        console=console,
        transient=transient,
        disable=not console.is_terminal,
    )


#: seconds a process may take to reach a command (Python's start-up and the imports: 0.16 s
#: here): a longer time read from ``/proc`` is another program's or clocks that do not match
#: (a container's). /proc dates a process from its fork, and a shell runs the last command of
#: ``bash -c`` or ``( ... )`` in its own process: ``(pip install ... && mdvae denoise ...)``
#: read 25 s for a command that took 1.2 (with a limit of 60 s)
STARTUP_LIMIT_S = 2.0


def process_seconds(fallback_start: float) -> float:
    """Seconds since this process started (what a user waited for a command: Python's and the
    libraries' start-up included), from ``/proc`` where the system has it; elsewhere, or where
    its clocks disagree with ours, since ``fallback_start`` (a ``time.perf_counter()`` value
    taken when the command began)."""
    import time

    own = time.perf_counter() - fallback_start
    try:
        with open("/proc/self/stat") as fh:  # field 22: start time, clock ticks after boot
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
    except (OSError, ValueError, IndexError):
        return own
    since = uptime - ticks / os.sysconf("SC_CLK_TCK")
    # /proc counts in clock ticks (10 ms): a process younger than one reads as 0
    return since if own - 0.02 <= since <= own + STARTUP_LIMIT_S else own


def on_command_line(param: str) -> bool:
    """Whether the command line names the option of parameter ``param`` (not its default)."""
    ctx = click.get_current_context(silent=True)
    given = click.core.ParameterSource.COMMANDLINE
    return ctx is not None and ctx.get_parameter_source(param) is given
