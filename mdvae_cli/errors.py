"""Exceptions whose message is one line the CLI prints as ``error: ...``."""


class MdvaeError(Exception):
    """A user-facing failure: bad input, unreadable file, impossible request.

    The message is a single line; the CLI prints it as ``error: <message>`` and exits non-zero.
    """


class InputError(MdvaeError):
    """The input file or option is malformed or inconsistent."""


class NotAvailableError(MdvaeError):
    """A feature that exists in the CLI but cannot run here (e.g. no trained weights)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (what ``timeout``, ``kill`` and job schedulers send), raised in the main thread
    as Ctrl-C's KeyboardInterrupt is, so that a half-written output is removed on the way out
    (``fileio.write_atomic``) instead of left behind by a process killed mid-write."""


#: the exit status of a process ended by ``signal`` (the shell's 128 + signal number)
INTERRUPTED_CODE, TERMINATED_CODE = 130, 143


def stop_words(exc: KeyboardInterrupt) -> tuple[str, int]:
    """The one-line message and exit status of a stop: Ctrl-C or SIGTERM."""
    if isinstance(exc, Terminated):
        return "terminated", TERMINATED_CODE
    return "interrupted", INTERRUPTED_CODE


def diverged(what: str, step: int, detail: str, lr_option: str = "--lr") -> InputError:
    """The error a training loop raises once its loss or weights stop being finite."""
    return InputError(
        f"{what} diverged at step {step} ({detail}): lower {lr_option}; nothing was saved from "
        "the diverged weights"
    )
