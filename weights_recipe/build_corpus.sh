#!/usr/bin/env bash
# Build the training and benchmark corpus: ../shared/data/{cmu,hdm05} -> data/corpus (git-ignored).
#
#   weights_recipe/build_corpus.sh [OUT_DIR]      (default: data/corpus)
#
# Every CMU trial (ASF/AMC, both BVH conversions, the donor-skeleton AMCs) and every HDM05 clip
# is retargeted onto the built-in SMPL-layout body and written as an AMASS-style .npz at 30 fps
# under OUT_DIR/cmu/ and OUT_DIR/hdm05/; OUT_DIR/split.json lists the files of each split
# (train, val, test, unseen_val, unseen_test; held-out subjects: weights_recipe/cmu_split.json)
# and OUT_DIR/summary.json the per-file retarget errors and checks. About 3-5 minutes on 2
# cores. Environment: DATA (folder holding cmu/ and hdm05/, default ../shared/data next to the
# repository), JOBS (worker processes, default 2).
# Terms: "The data used in this project was obtained from mocap.cs.cmu.edu. The database was
# created with funding from NSF EIA-0196217." Converted data may not be redistributed for sale.
# HDM05 (CC BY-SA 3.0; Mueller et al., Tech. Rep. CG-2007-2, Universitaet Bonn, 2007) is held
# out as test data and never trains the shipped weights.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
src="${DATA:-$repo/../shared/data}"
out="${1:-$repo/data/corpus}"
exec mdvae import "$src/cmu" "$src/hdm05" -o "$out" --corpus --split "$here/cmu_split.json" \
    --fps 30 --jobs "${JOBS:-2}"
