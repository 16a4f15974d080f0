#!/usr/bin/env bash
# The data-scaling curve at the end of prior_v3's whole schedule (issue 30): the recipe of
# build_v3.sh step 2 (weights_recipe/prior_config.json, seed 0) on 25 % and 50 % of the
# training minutes (whole files, seeded, nested subsets), with prior_v3's own schedule: 5
# epochs, then --resume to 10, then to 15 (two warm restarts of the cosine). The 100 % point
# is prior_v3 itself. Each step resumes where the folder stands, so the script can be
# stopped and run again. One CPU thread; 25 %: ~50 min, 50 %: ~1 h 40 min.
#   bash weights_recipe/scaling_converged.sh 25     # or 50
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1
pct=${1:?usage: scaling_converged.sh 25|50}
frac=$(python3 -c "print($pct / 100)")
out=runs/scaling_conv/full_$pct
done_epochs() {  # epochs finished in the folder (0 = none)
    [ -f "$out/last.json" ] || { echo 0; return; }
    python3 -c "import json; print(json.load(open('$out/last.json'))['epoch'] + 1)"
}
for epochs in 5 10 15; do
    have=$(done_epochs)
    [ "$have" -ge "$epochs" ] && continue
    if [ "$have" -gt 0 ]; then  # the run's own config.json holds the rest
        mdvae train-prior data/corpus -o "$out" --resume --epochs "$epochs" \
            --threads 1 --device cpu
    else
        mdvae train-prior data/corpus --split data/corpus/split.json -o "$out" \
            --config weights_recipe/prior_config.json --data-fraction "$frac" \
            --epochs "$epochs" --threads 1 --device cpu
    fi
done
