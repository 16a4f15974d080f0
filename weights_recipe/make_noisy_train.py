"""Noisy training data for the shipped denoiser: every train-split file of the corpus with
Pose-NDF noise of a std drawn per file uniformly in [0.10, 0.20] rad (seeded by the path).

    python weights_recipe/make_noisy_train.py data/corpus data/corpus_noisy_train --seed 0
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.motion.noise import add_pose_noise, file_rng
from mdvae_cli.train.corpus import read_split


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sigma-min", type=float, default=0.10)
    ap.add_argument("--sigma-max", type=float, default=0.20)
    ap.add_argument("--split", default="train")
    args = ap.parse_args()
    files = read_split(args.corpus / "split.json")[args.split]
    sigmas = {}
    for f in files:
        rel = f.relative_to(args.corpus)
        rng = file_rng(args.seed, rel)
        sigma = float(rng.uniform(args.sigma_min, args.sigma_max))
        save_motion(add_pose_noise(load_motion(f), sigma, rng), args.out / rel)
        sigmas[rel.as_posix()] = round(sigma, 4)
    (args.out / "sigmas.json").write_text(json.dumps(sigmas, indent=1) + "\n")
    print(f"wrote {len(files)} noisy files to {args.out}")


if __name__ == "__main__":
    main()
