#!/usr/bin/env bash
# One lease of a GPU for the prior (issue 30), as one command of at most SECONDS (default 540):
#
#   OUT=folder bash weights_recipe/gpu_session.sh [SECONDS]
#
# 1. times the training step, eager and as a CUDA graph, at batch 64 / 256 / 1024
#    (benchmarks/train_speed.py -> OUT/speed.jsonl);
# 2. runs the GPU tests (tests/test_prior_step.py): where they fail, the runs go eager;
# 3. fixes every run's schedule to end inside the lease (gpu_plan.py: steps from the measured
#    speed; each run's config.json records its epochs, so its command reproduces it);
# 4. trains four priors side by side on data/corpus_pack (pack_corpus.py; carried to the
#    machine), prior_gpu_config.json's recipe (batch 1024, seed 0):
#      full_lr16  all training minutes, lr 1.6e-2 (the rate measured best over one epoch)
#      full_lr8   all training minutes, lr 8e-3 (half of it: steadier over long schedules)
#      half       50 % of the minutes, lr 8e-3 (the data-scaling curve)
#      quarter    25 % of the minutes, lr 8e-3
#    every run the same number of steps, validated about every 190 steps, stopped and
#    checkpointed by --max-minutes if the schedule would outlast the lease;
# 5. packs each run folder into OUT/NAME.tar.gz and the log into OUT/session.log.
# Without a GPU (DEVICE=cpu) the same steps run on the CPU: a rehearsal with tiny budgets.
set -uo pipefail
cd "$(dirname "$0")/.."
budget="${1:-540}"
out="${OUT:-runs/gpu_session}"
corpus="${CORPUS:-data/corpus_pack}"
device="${DEVICE:-cuda}"
runs_dir="${RUNS:-runs/gpu}"
mkdir -p "$out" "$runs_dir"
start=$(date +%s)
left() { echo $((budget - ($(date +%s) - start))); }
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
log="$out/session.log"
say() { echo "[$(($(date +%s) - start)) s] $*" >>"$log"; }
mdvae=(python3 -m mdvae_cli.cli.main) # the package need not be installed there

say "start: $(nproc) cores; $(python3 -c 'import torch; print("torch", torch.__version__)')"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total \
    --format=csv,noheader >>"$log" 2>&1

# 1. the step's speed
timeout 150 python3 benchmarks/train_speed.py --device "$device" --batch "${BATCHES:-64,256,1024}" \
    --steps "${SPEED_STEPS:-20}" --json-lines >"$out/speed.jsonl" 2>>"$log"
say "speed: rc $?"

# 2. the GPU tests (the graphed step against the eager one, a graphed run resumed on the CPU):
#    where they fail, the runs go without the graph
eager=""
if [ "$device" = cuda ] && [ -z "${SKIP_TESTS:-}" ]; then
    timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_prior_step.py >>"$log" 2>&1
    rc=$?
    say "tests: rc $rc"
    [ $rc = 0 ] || eager=--eager
fi

# 3. the plan: training seconds = what is left less loading (~60 s) and packing (~30 s)
names=(full_lr16 full_lr8 half quarter)
fractions=(1.0 1.0 0.5 0.25)
rates=(0.016 0.008 0.008 0.008)
epoch_steps=(95 95 48 24) # batch 1024: 98,058 / 49,188 / 25,114 windows an epoch
val_every=(2 2 4 8)
keep="${KEEP:-${#names[@]}}" # the first KEEP runs alone (more steps each)
names=("${names[@]:0:$keep}")
train_s=$(($(left) - ${LOAD_S:-60} - ${PACK_S:-30}))
read -r mode steps < <(python3 weights_recipe/gpu_plan.py "$out/speed.jsonl" "$train_s" \
    "${#names[@]}" $eager)
steps="${STEPS:-$steps}" # a rehearsal fixes its own
graph_flag=$([ "$mode" = graph ] && echo --cuda-graph || echo --no-cuda-graph)
say "plan: $mode step, $steps steps a run in $train_s s"

# 4. the runs, side by side
minutes=$(python3 -c "print(max(0.1, ($(left) - ${PACK_S:-30}) / 60))")
pids=()
for i in "${!names[@]}"; do
    epochs=$(((steps + epoch_steps[i] - 1) / epoch_steps[i]))
    dir="$runs_dir/${names[$i]}"
    rm -rf "$dir"
    mkdir -p "$dir"
    timeout $(($(left) - 10)) "${mdvae[@]}" train-prior "$corpus" --split "$corpus/split.json" -o "$dir" \
        --config weights_recipe/prior_gpu_config.json --data-fraction "${fractions[$i]}" \
        --lr "${rates[$i]}" --epochs "$epochs" --val-every "${val_every[$i]}" "$graph_flag" \
        --max-minutes "$minutes" --device "$device" --threads 4 --json >"$dir/run.log" 2>&1 &
    pids+=($!)
    say "run ${names[$i]}: $epochs epochs of ${epoch_steps[$i]} steps (pid $!)"
done

for i in "${!pids[@]}"; do
    wait "${pids[$i]}"
    say "run ${names[$i]}: rc $?, $(tail -c 400 "$runs_dir/${names[$i]}/run.log" | tr '\n' ' ')"
done

# 5. pack
for name in "${names[@]}"; do
    tar -czf "$out/$name.tar.gz" -C "$runs_dir" "$name"
done
say "packed: $(ls "$out" | tr '\n' ' ')"
