"""``mdvae train-prior`` and ``mdvae fit-dataset``."""

from __future__ import annotations

import click

from mdvae_cli.cli.common import handle_errors
from mdvae_cli.errors import NotAvailableError


@click.command("train-prior", context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@handle_errors
def train_prior(args) -> None:
    """Train the Motion-DVAE prior on clean motion files (not yet available)."""
    raise NotAvailableError("train-prior is not yet available in this version")


@click.command("fit-dataset", context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@handle_errors
def fit_dataset(args) -> None:
    """Fit the denoiser to a folder of noisy files, unsupervised (not yet available)."""
    raise NotAvailableError("fit-dataset is not yet available in this version")


COMMANDS = [train_prior, fit_dataset]
