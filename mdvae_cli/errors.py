"""Exceptions whose message is one line the CLI prints as ``error: ...``."""


class MdvaeError(Exception):
    """A user-facing failure: bad input, unreadable file, impossible request.

    The message is a single line; the CLI prints it as ``error: <message>`` and exits non-zero.
    """


class InputError(MdvaeError):
    """The input file or option is malformed or inconsistent."""


class NotAvailableError(MdvaeError):
    """A feature that exists in the CLI but cannot run here (e.g. no trained weights)."""


def diverged(what: str, step: int, detail: str, lr_option: str = "--lr") -> InputError:
    """The error a training loop raises once its loss or weights stop being finite."""
    return InputError(
        f"{what} diverged at step {step} ({detail}): lower {lr_option}; nothing was saved from "
        "the diverged weights"
    )
