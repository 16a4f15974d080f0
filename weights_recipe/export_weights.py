"""Copy a trained prior run and a fitted denoiser into the package's shipped weights.

python weights_recipe/export_weights.py runs/prior_rw30 runs/denoiser_distilled
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.model.prior_model import load_prior

TARGET = Path(__file__).resolve().parents[1] / "mdvae_cli" / "weights"


def main() -> None:
    prior_run, denoiser_run = Path(sys.argv[1]), Path(sys.argv[2])
    load_prior(prior_run)  # refuse to ship what does not load
    load_denoiser(denoiser_run)
    for src, name in ((prior_run / "best", "prior"), (denoiser_run / "denoiser", "denoiser")):
        for suffix in (".npz", ".json"):
            shutil.copyfile(src.with_suffix(suffix), TARGET / f"{name}{suffix}")
            print(f"{src.with_suffix(suffix)} -> {TARGET / (name + suffix)}")


if __name__ == "__main__":
    main()
