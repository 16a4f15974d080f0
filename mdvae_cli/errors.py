"""Exceptions whose message is one line the CLI prints as ``error: ...``."""


class MdvaeError(Exception):
    """A user-facing failure: bad input, unreadable file, impossible request.

    The message is a single line; the CLI prints it as ``error: <message>`` and exits non-zero.
    """


class InputError(MdvaeError):
    """The input file or option is malformed or inconsistent."""


class NotAvailableError(MdvaeError):
    """A feature that exists in the CLI but cannot run here (e.g. no trained weights)."""
