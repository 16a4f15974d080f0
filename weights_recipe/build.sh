#!/usr/bin/env bash
# Rebuild the shipped weights from scratch (see README.md in this folder).
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1
# 1. the CMU corpus in AMASS layout (30 Hz, built-in body) and its train/val/test split by subject
bash weights_recipe/build_cmu_corpus.sh   # mdvae import ../shared/data/cmu -o data/cmu_amass --cmu-corpus ...

# 2. the prior (seed 0), in four stages; each stage continues from the previous one's best
#    checkpoint (stages b-d with `--init-from`, which widens an older architecture exactly).
# 2a. the first architecture (no decoder z-skip, no encoder links): 12 epochs, then resumed to
#     26 (a warm restart of the cosine learning-rate schedule)
mdvae train-prior data/cmu_amass --split data/cmu_amass/split.json -o runs/prior_v1 \
    --epochs 12 --stride 10 --batch-size 64 --lr 2e-3 --kl-warmup 2000 --seed 0 \
    --device cpu --threads 1 --no-decoder-z-skip --no-encoder-reads-decoder --no-encoder-x-skip
mdvae train-prior data/cmu_amass -o runs/prior_v1 --resume --epochs 26 --threads 1
# 2b. + decoder head on [h_t, z_t] and an encoder that reads the decoder's state; sharper
#     decoder likelihood (sigma_x^2 = 1/10) and body weight 0.3; stopped after 5 of 14 epochs
mdvae train-prior data/cmu_amass -o runs/prior_ed10 --config runs/prior_v1/config.json \
    --init-from runs/prior_v1/best.npz --decoder-z-skip --encoder-reads-decoder \
    --no-encoder-x-skip --recon-weight 10 --body-weight 0.3 --kl-warmup 0 --lr 1e-3 \
    --epochs 14 --max-steps 930 --threads 1
# 2c. + the encoder reads x_t; velocity columns at 1/10 of the reconstruction weight; body
#     weight 1: 14 epochs.
mdvae train-prior data/cmu_amass -o runs/prior_full --config runs/prior_v1/config.json \
    --init-from runs/prior_ed10/best.npz --decoder-z-skip --encoder-reads-decoder \
    --encoder-x-skip --recon-weight 10 --velocity-weight 0.1 --body-weight 1 --kl-warmup 0 \
    --lr 1e-3 --epochs 14 --threads 1
# 2d. sharper still: recon weight 30, body weight 2. A 56-epoch cosine schedule stopped after 29
#     epochs (5,394 steps), then annealed over 7 more by resuming with --epochs 36. This is the
#     shipped prior (runs/prior_rw30/best.npz, epoch 31).
mdvae train-prior data/cmu_amass -o runs/prior_rw30 --config runs/prior_full/config.json \
    --init-from runs/prior_full/best.npz --kl-warmup 0 --lr 5e-4 --epochs 56 --max-steps 5394 \
    --recon-weight 30 --body-weight 2 --threads 1
mdvae train-prior data/cmu_amass -o runs/prior_rw30 --resume --epochs 36 --threads 1

# 3. noisy copies of the train split, sigma ~ U(0.10, 0.20) per file (seed 0)
python weights_recipe/make_noisy_train.py data/cmu_amass data/cmu_noisy_train --seed 0

# 4. unsupervised denoising learning on the noisy train clips only (no clean data), on the
#    shipped prior; the inference networks read the noisy motion through an 11-frame
#    Savitzky-Golay filter (input_window), the likelihood scores the raw observations
mdvae fit-dataset data/cmu_noisy_train --prior runs/prior_rw30 -o runs/denoiser_rw30 \
    --config weights_recipe/denoiser_config_filtered.json --threads 2

# 5. amortised refinement: every noisy train window (and its mirror image) refined for 50 steps
#    on its own noisy data, then the encoder and x0 predictor trained for 6 epochs to output
#    the refined posterior means in one pass (still no clean data)
mdvae fit-dataset data/cmu_noisy_train --init-from runs/denoiser_rw30 -o runs/denoiser_distilled \
    --epochs 0 --distill-epochs 6 --mirror-augment --device cpu --threads 2

# 6. copy into the package
python weights_recipe/export_weights.py runs/prior_rw30 runs/denoiser_distilled
