"""``mdvae denoise``."""

from __future__ import annotations

import click

from mdvae_cli.cli.common import handle_errors
from mdvae_cli.errors import NotAvailableError


@click.command("denoise", context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@handle_errors
def denoise(args) -> None:
    """Denoise motion files with the learned prior (not yet available)."""
    raise NotAvailableError("denoise is not yet available in this version")


COMMANDS = [denoise]
