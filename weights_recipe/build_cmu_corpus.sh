#!/usr/bin/env bash
# Build the CMU training corpus: ../shared/data/cmu -> data/cmu_amass (git-ignored).
#
#   weights_recipe/build_cmu_corpus.sh [OUT_DIR]      (default: data/cmu_amass)
#
# Every CMU trial is retargeted onto the built-in SMPL-layout body and written as an AMASS-style
# .npz at 30 fps, mirroring the corpus tree; OUT_DIR/split.json lists the files of each split
# (held-out subjects: weights_recipe/cmu_split_shipped.json) and OUT_DIR/summary.json the per-file
# retarget errors and checks. About 2-4 minutes on 2 cores. Environment: CMU_DATA (corpus
# folder, default ../shared/data/cmu next to the repository), JOBS (worker processes, default 2).
# Terms: "The data used in this project was obtained from mocap.cs.cmu.edu. The database was
# created with funding from NSF EIA-0196217." Converted data may not be redistributed for sale.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
src="${CMU_DATA:-$repo/../shared/data/cmu}"
out="${1:-$repo/data/cmu_amass}"
exec mdvae import "$src" -o "$out" --cmu-corpus --split "$here/cmu_split_shipped.json" --fps 30 \
    --jobs "${JOBS:-2}"
