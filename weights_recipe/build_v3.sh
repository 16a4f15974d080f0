#!/usr/bin/env bash
# The retrained weights of issue 19 (not shipped yet: see README.md in this folder).
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1
# 1. the corpus: every CMU motion and the HDM05 test clips, in AMASS layout (30 Hz, built-in
#    body), split by subject into train / val / test / unseen_val / unseen_test
bash weights_recipe/build_corpus.sh   # mdvae import ../shared/data/{cmu,hdm05} -o data/corpus --corpus ...

# 2. the prior (seed 0), one run from scratch: 5 epochs of ~98,000 windows (the training
#    motions as captured, played at 0.8x and 1.25x, and all of them mirrored), batch 64,
#    recon weight 30, velocity weight 0.1, body weight 2, lr 1e-3 -> 5e-5 (cosine), KL warm-up
#    2,000 steps; the best checkpoint on the val + unseen_val windows is kept
mdvae train-prior data/corpus --split data/corpus/split.json -o runs/prior_v3 \
    --config weights_recipe/prior_config.json --threads 1 --device cpu

# 3. noisy copies of the train split, sigma ~ U(0.10, 0.20) per file (seed 0)
python weights_recipe/make_noisy_train.py data/corpus data/corpus_noisy_train --seed 0

# 4. unsupervised denoising learning on the noisy train copies only (no clean data): ELBO fit
#    (4 epochs, stride 20) of the full windows, their mirror images and short takes of 6-30 frames, then
#    amortised refinement (targets from 50 refinement steps per window, 4 epochs)
mdvae fit-dataset data/corpus_noisy_train --prior runs/prior_v3 -o runs/denoiser_v3 \
    --config weights_recipe/denoiser_config_v3.json --threads 2

# 5. copy into the package (once they beat the shipped weights)
python weights_recipe/export_weights.py runs/prior_v3 runs/denoiser_v3
