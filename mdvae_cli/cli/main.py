"""The ``mdvae`` entry point: registers one small module per command."""

from __future__ import annotations

import click

from mdvae_cli import __version__
from mdvae_cli.cli import (
    add_noise,
    denoise,
    eval_cmd,
    export_bvh,
    export_mesh,
    fit_dataset_cmd,
    import_cmd,
    sample,
    train,
    view_cmd,
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mdvae")
def cli() -> None:
    """Clean up human motion-capture files with a learned motion prior (Motion-DVAE).

    \b
    Typical pipeline:
      mdvae add-noise --sigma 0.15 clean.npz -o noisy.npz
      mdvae denoise noisy.npz -o cleaned.npz
      mdvae eval --gt clean.npz --pred cleaned.npz

    Files are AMASS-style .npz (poses, trans, betas, mocap_framerate). The file commands
    (add-noise, denoise, eval, export-mesh, import) take files or folders; folders are
    mirrored into the output folder.
    """


for module in (
    train,
    fit_dataset_cmd,
    denoise,
    add_noise,
    eval_cmd,
    export_bvh,
    export_mesh,
    export_bvh,
    import_cmd,
    sample,
    view_cmd,
):
    for command in module.COMMANDS:
        cli.add_command(command)


if __name__ == "__main__":  # pragma: no cover
    cli()
