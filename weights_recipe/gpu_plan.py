"""How many steps the runs of one GPU lease take (``gpu_session.sh``), from the step's speed
measured at the lease's start (``benchmarks/train_speed.py --json-lines``).

Each run's cosine schedule must end inside the lease, so its epochs are fixed here, once, from
the seconds left and the measured seconds per step of batch 1024: graphed (the runs share the
GPU, which replays one graph at a time) or, where the capture failed, eager (bound by each
process's own launches: the runs overlap about two-fold). The epochs chosen are written into
each run's config.json, so a run is reproduced by its recorded command.

    python weights_recipe/gpu_plan.py SPEED_JSONL SECONDS RUNS [--eager]  ->  "MODE STEPS"
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

#: steps a run may take, whatever the speed (a run of fewer is no use; more is past
#: convergence at this corpus's size)
MIN_STEPS, MAX_STEPS = 200, 40_000
#: what validation, checkpoints and the host add to the timed steps
OVERHEAD = 1.3
#: seconds per step of batch 1024 where nothing was measured (the eager step on an H100)
FALLBACK = 0.25


def plan(rows: list[dict], seconds: float, runs: int, eager: bool = False) -> tuple[str, int]:
    """("graph" or "eager", steps per run) for ``runs`` runs in ``seconds`` of training;
    ``eager``: the graphed step failed its tests, so the runs go without it."""
    timed = {r.get("mode"): r["s_per_step"] for r in rows if r.get("batch") == 1024}
    if "graph" in timed and not eager:
        mode, per_step, share = "graph", timed["graph"], runs
    else:
        mode, per_step, share = "eager", timed.get("eager", FALLBACK), max(1.0, runs / 2)
    steps = int(seconds / (per_step * share * OVERHEAD))
    return mode, max(MIN_STEPS, min(MAX_STEPS, steps))


def read_rows(path: Path) -> list[dict]:
    rows = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict) and "s_per_step" in row:
                rows.append(row)
    return rows


if __name__ == "__main__":
    rows = read_rows(Path(sys.argv[1]))
    mode, steps = plan(rows, float(sys.argv[2]), int(sys.argv[3]), "--eager" in sys.argv[4:])
    print(mode, steps)
