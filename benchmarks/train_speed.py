"""Speed of one training step of the prior: seconds per step, steps/s and windows/s.

The step is the shipped recipe's whole step (``weights_recipe/prior_config.json``): encoder,
decoder and prior over 60-frame windows, the body term on every ``body_frame_stride``-th frame,
the backward pass, gradient clipping and Adam. Windows are random states of a realistic scale
(the arithmetic does not depend on the values). Prints a markdown table for every device and
batch size asked for; with ``--json``, one JSON object (with ``s_per_step`` at its top level
when one device and one batch size were asked for).

    python benchmarks/train_speed.py                       # cpu (+ cuda where present), 64/256/1024
    python benchmarks/train_speed.py --device cpu --batch 64 --threads 2 --json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.optim import clipped_step
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.prior_loss import prior_losses, spread_vertex_ids
from mdvae_cli.train.train_config import TrainConfig

RECIPE = Path(__file__).resolve().parents[1] / "weights_recipe" / "prior_config.json"


def synthetic_windows(n: int, cfg: TrainConfig, seed: int = 0) -> WindowSet:
    """``n`` random windows of (window + 1) states, about the size of real ones."""
    g = torch.Generator().manual_seed(seed)
    D = cfg.model.state_dim
    x = 0.2 * torch.randn(n, cfg.window, D, generator=g)
    x0 = 0.2 * torch.randn(n, D, generator=g)
    return WindowSet(x0, x, torch.zeros(n, 16))


def time_steps(cfg: TrainConfig, device: torch.device, batch: int, steps: int) -> float:
    """Seconds per training step (median of ``steps`` timed steps, after two warm-up ones)."""
    torch.manual_seed(cfg.seed)
    body = BodyModel(load_body_model(None)).to(device)
    vertex_ids = spread_vertex_ids(body.v_template.shape[0], cfg.body_vertices).to(device)
    data = synthetic_windows(batch, cfg)
    model = PriorModel(cfg.model)
    model.normalizer.fit(data.x0, data.x)
    model.to(device)
    data = WindowSet(*(t.to(device) for t in (data.x0, data.x, data.betas)))
    opt = torch.optim.Adam(model.dvae.parameters(), lr=cfg.lr)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def step() -> None:
        terms = prior_losses(
            model, model.dvae, data, body, vertex_ids, 0.5, cfg.body_weight,
            cfg.body_frame_stride, cfg.recon_weight, cfg.velocity_weight,
        )  # fmt: skip
        clipped_step(opt, terms["loss"], model.dvae.parameters(), cfg.grad_clip)

    for _ in range(2):
        step()
    times = []
    for _ in range(steps):
        sync()
        t0 = time.perf_counter()
        step()
        sync()
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto (cpu, and cuda if present)")
    ap.add_argument("--batch", default="64,256,1024", help="batch sizes, comma-separated")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: torch's)")
    ap.add_argument("--steps", type=int, default=10, help="timed steps per row")
    ap.add_argument("--config", type=Path, default=RECIPE, help="training config (the recipe)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = TrainConfig.from_dict(json.loads(args.config.read_text()))
    if args.device == "auto":
        devices = ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]
    else:
        devices = [args.device]
    rows = []
    for name in devices:
        for batch in (int(b) for b in args.batch.split(",")):
            s = time_steps(cfg, torch.device(name), batch, args.steps)
            rows.append(
                {"device": name, "batch": batch, "s_per_step": s, "steps_per_s": 1 / s,
                 "windows_per_s": batch / s}
            )  # fmt: skip
    result = {
        "machine": platform.processor() or platform.machine(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "rows": rows,
    }
    if len(rows) == 1:
        result["s_per_step"] = rows[0]["s_per_step"]
    if args.json:
        print(json.dumps(result))
        return result
    print(f"torch {result['torch']}, {result['threads']} CPU thread(s)\n")
    print("| device | batch | s/step | steps/s | windows/s |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['device']} | {r['batch']} | {r['s_per_step']:.4f} | {r['steps_per_s']:.2f} "
            f"| {r['windows_per_s']:,.0f} |"
        )
    return result


if __name__ == "__main__":
    main()
