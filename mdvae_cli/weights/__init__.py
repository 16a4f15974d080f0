"""Weights shipped with the package: the default prior and denoiser (see weights_recipe/)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from mdvae_cli.errors import NotAvailableError

NAMES = ("prior", "denoiser")


def default_weights(name: str) -> Path:
    """Path of a shipped checkpoint (``prior`` or ``denoiser``): an ``.npz`` beside a ``.json``."""
    path = Path(str(resources.files("mdvae_cli.weights") / f"{name}.npz"))
    if not path.exists():
        raise NotAvailableError(
            f"no shipped {name} weights in this install ({path.name} missing); pass one explicitly"
        )
    return path
