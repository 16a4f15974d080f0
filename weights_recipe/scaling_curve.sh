#!/usr/bin/env bash
# The data-scaling curve and the augmentation ablation of docs/model.md ("How much more motion
# would buy"): the shipped prior's recipe (weights_recipe/prior_config.json) at a fixed budget
# of about 1,530 steps (the shipped prior takes 5 epochs, 7,660 steps), on 25 / 50 / 100 % of
# the training minutes (whole files, seeded, nested subsets), and at 100 % without the
# time-warp and without any augmentation. Then each prior's reconstruction of the unseen_test
# windows (benchmarks/prior_scaling.py). About 15-40 minutes of one CPU thread per run.
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1
corpus=data/corpus
run() {  # run NAME EPOCHS EXTRA-OPTIONS...
    local name=$1 epochs=$2; shift 2
    mdvae train-prior "$corpus" --split "$corpus/split.json" -o "runs/scaling/$name" \
        --config weights_recipe/prior_config.json --kl-warmup 500 --epochs "$epochs" \
        --threads 1 --device cpu "$@"
}
# `scaling_curve.sh curve` runs the first three only (the curve without the ablation).
run full_100 1
run full_50 2 --data-fraction 0.5
run full_25 4 --data-fraction 0.25
[ "${1:-all}" = curve ] && exit 0
run mirror_only_100 3 --speeds 1
run no_augment_100 6 --speeds 1 --no-mirror-augment
