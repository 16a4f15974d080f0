#!/usr/bin/env bash
# The prior in short GPU runs (issue 30): batch 1024 (a GPU step costs about what a step of 64
# does; docs/benchmarks.md, "Training step speed"), from a compact copy of the corpus, under a
# wall-clock budget. The run validates and checkpoints every epoch (96 steps) and when the
# budget ends, and the next call resumes it exactly where it stopped, on a GPU or, where there
# is none, on the CPU (the same steps, slower), until its schedule is done.
#
#   bash weights_recipe/gpu_prior.sh [MINUTES]     (default 7; each call adds MINUTES of training)
#
# The copy (data/corpus_pack, ~49 MiB: the train, val and unseen_val lists, body columns only)
# is made once by pack_corpus.py from data/corpus (build_corpus.sh); on a machine without
# ../shared, carry it. Windows built from it are the corpus's own, bit for bit.
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${1:-7}"
run="${RUN:-runs/prior_gpu}"
[ -d data/corpus_pack ] || python3 weights_recipe/pack_corpus.py data/corpus data/corpus_pack
if [ -f "$run/last.npz" ]; then
    mdvae train-prior data/corpus_pack -o "$run" --resume --max-minutes "$minutes"
else
    mdvae train-prior data/corpus_pack --split data/corpus_pack/split.json -o "$run" \
        --config weights_recipe/prior_gpu_config.json --max-minutes "$minutes"
fi
