"""What every command shares: the console, error handling, common options, batch runs."""

from __future__ import annotations

import functools
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

from mdvae_cli.errors import MdvaeError, NotAvailableError

#: the one console for human-readable output; machine output (--json) goes to stdout directly
console = Console(stderr=True, highlight=False)


def fail(message: str, code: int = 1) -> None:
    """Print ``error: message`` (one line) and exit with ``code``."""
    console.print(f"[bold red]error:[/] {escape(' '.join(str(message).split()))}", soft_wrap=True)
    sys.exit(code)


def handle_errors(fn: Callable) -> Callable:
    """Turn library exceptions into one-line errors with a non-zero exit code.

    MdvaeError -> exit 1 (NotAvailableError -> exit 2); any other exception -> exit 1 with its
    type and message, unless MDVAE_DEBUG=1, which re-raises for a traceback.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except NotAvailableError as exc:
            fail(str(exc), code=2)
        except MdvaeError as exc:
            fail(str(exc))
        except KeyboardInterrupt:
            fail("interrupted", code=130)
        except (click.exceptions.Exit, click.ClickException, SystemExit):
            raise
        except OSError as exc:  # the file system's refusal (name too long, no permission...)
            if os.environ.get("MDVAE_DEBUG"):
                raise
            fail(os_error_words(exc))
        except Exception as exc:
            if os.environ.get("MDVAE_DEBUG"):
                raise
            fail(f"{type(exc).__name__}: {exc} (set MDVAE_DEBUG=1 for a traceback)")

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
