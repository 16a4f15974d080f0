#!/usr/bin/env bash
# A typical batch pipeline on the bundled example: noise it, clean it, score both.
set -euo pipefail
cd "$(dirname "$0")"
out=$(mktemp -d)
mdvae add-noise --sigma 0.15 --seed 1 walk.npz -o "$out/noisy.npz"
mdvae denoise "$out/noisy.npz" -o "$out/clean.npz"
mdvae eval --gt walk.npz --pred "$out/noisy.npz" --json > "$out/noisy_scores.json"
mdvae eval --gt walk.npz --pred "$out/clean.npz" --json > "$out/clean_scores.json"
python3 -c "import json,sys; a,b=(json.load(open(f))['mean']['v2v_cm'] for f in sys.argv[1:]); print(f'V2V noisy {a:.2f} cm -> denoised {b:.2f} cm')" "$out/noisy_scores.json" "$out/clean_scores.json"
