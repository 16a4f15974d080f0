"""Body-model file loaders (placeholder until the loaders land)."""

from __future__ import annotations

from pathlib import Path

from mdvae_cli.body.data import BodyModelData


def load_body_model(path: Path | str | None = None) -> BodyModelData:
    """Load an SMPL-family body model file, or the built-in body when ``path`` is None."""
    from mdvae_cli.body.builtin import builtin_body_model

    if path is None:
        return builtin_body_model()
    raise NotImplementedError
