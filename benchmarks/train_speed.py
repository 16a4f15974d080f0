"""Speed of one training step of the prior: seconds per step, steps/s and windows/s.

The step is the shipped recipe's whole step (``weights_recipe/prior_config.json``): encoder,
decoder and prior over 60-frame windows, the body term on every ``body_frame_stride``-th frame,
the backward pass, gradient clipping and Adam. Windows are random states of a realistic scale
(the arithmetic does not depend on the values). Prints a markdown table for every device and
batch size asked for, with the step's arithmetic (GFLOP of matrix products, forward and
backward, counted by torch) and the rate it reached against the device's rate on one plain
matrix product of the same width (the ceiling a step made only of such products could
reach); with ``--json``, one JSON object (with ``s_per_step`` at its top level when one device
and one batch size were asked for). On a GPU every batch size is timed twice: the eager step
and the step captured as a CUDA graph (``train.prior_step``, what ``train-prior`` runs there;
``--no-graph`` leaves it out); ``--json-lines`` prints each row as it is timed.

The model is the one ``train-prior`` builds from the recipe (its current layout: the decoder
head reads z_t, the encoder reads the decoder's state and x_t), not a legacy checkpoint's.
``--hidden 128,256`` times each recurrent width (the capacity point) and adds what the width
costs at inference: one regression-mode pass (encoder means, then the decoder, no gradient)
over 300 windows of 60 frames, a 10-minute take's worth at 30 Hz.

    python benchmarks/train_speed.py                       # cpu (+ cuda where present), 64/256/1024
    python benchmarks/train_speed.py --device cpu --batch 64 --threads 2 --json
    python benchmarks/train_speed.py --device cpu --batch 64 --hidden 128,256
    python benchmarks/train_speed.py --device cuda --batch 64,1024 --steps 10 --json-lines
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.prior_loss import prior_losses, spread_vertex_ids
from mdvae_cli.train.prior_step import WARM_STEPS, PriorStep
from mdvae_cli.train.train_config import TrainConfig

RECIPE = Path(__file__).resolve().parents[1] / "weights_recipe" / "prior_config.json"


def synthetic_windows(n: int, cfg: TrainConfig, seed: int = 0) -> WindowSet:
    """``n`` random windows of (window + 1) states, about the size of real ones."""
    g = torch.Generator().manual_seed(seed)
    D = cfg.model.state_dim
    x = 0.2 * torch.randn(n, cfg.window, D, generator=g)
    x0 = 0.2 * torch.randn(n, D, generator=g)
    return WindowSet(x0, x, torch.zeros(n, 16))


def matmul_rate(device: torch.device, rows: int = 1024, reps: int = 50) -> float:
    """GFLOP/s of one (rows x H) @ (H x 3H) product, H the recipe's width (128): a GRU's gates."""
    a = torch.randn(rows, 128, device=device)
    w = torch.randn(128, 384, device=device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for _ in range(3):
        a @ w
    sync()
    t0 = time.perf_counter()
    for _ in range(reps):
        a @ w
    sync()
    return 2 * rows * 128 * 384 * reps / (time.perf_counter() - t0) / 1e9


def step_gflop(cfg: TrainConfig, batch: int) -> float:
    """GFLOP of the matrix products in one training step (forward and backward), on CPU."""
    from torch.utils.flop_counter import FlopCounterMode

    model, body, vertex_ids, data = recipe_step_parts(cfg, torch.device("cpu"), batch)
    with FlopCounterMode(display=False) as counter:
        terms = prior_losses(
            model, model.dvae, data, body, vertex_ids, 0.5, cfg.body_weight,
            cfg.body_frame_stride, cfg.recon_weight, cfg.velocity_weight,
        )  # fmt: skip
        terms["loss"].backward()
    return counter.get_total_flops() / 1e9


def recipe_step_parts(cfg: TrainConfig, device: torch.device, batch: int):
    """The recipe's model (normaliser fitted), body, body-term vertices and ``batch`` windows."""
    torch.manual_seed(cfg.seed)
    body = BodyModel(load_body_model(None)).to(device)
    vertex_ids = spread_vertex_ids(body.v_template.shape[0], cfg.body_vertices).to(device)
    data = synthetic_windows(batch, cfg)
    model = PriorModel(cfg.model)
    model.normalizer.fit(data.x0, data.x)
    model.to(device)
    data = WindowSet(*(t.to(device) for t in (data.x0, data.x, data.betas)))
    return model, body, vertex_ids, data


def time_steps(cfg: TrainConfig, device: torch.device, batch: int, steps: int,
               graph: bool = False) -> tuple[float, str | None]:  # fmt: skip
    """Seconds per training step (median of ``steps`` timed steps, after the warm-up ones:
    two eager, or a graphed step's eager ones and its capture), as ``train-prior`` takes it
    (``train.prior_step.PriorStep``), and why the capture failed where it did."""
    model, body, vertex_ids, data = recipe_step_parts(cfg, device, batch)
    opt = torch.optim.Adam(model.dvae.parameters(), lr=cfg.lr)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    step = PriorStep(
        model, model.dvae, body, vertex_ids, opt, model.dvae.parameters(),
        recon_w=cfg.recon_weight, velocity_w=cfg.velocity_weight, body_w=cfg.body_weight,
        body_stride=cfg.body_frame_stride, grad_clip=cfg.grad_clip, graph=graph,
    )  # fmt: skip
    warm = WARM_STEPS + 2 if graph else 2
    for i in range(warm):
        step(data, cfg.lr, 0.5, i + 1)
    times = []
    for i in range(steps):
        sync()
        t0 = time.perf_counter()
        step(data, cfg.lr, 0.5, warm + i + 1)
        sync()
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2], step.failure


def inference_seconds(cfg: TrainConfig, device: torch.device, windows: int = 300) -> float:
    """Seconds of one regression-mode pass of the networks over ``windows`` windows (the
    encoder's means, then the decoder, no gradient): median of three after one warm-up."""
    model, _, _, data = recipe_step_parts(cfg, device, windows)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    times = []
    with torch.no_grad():
        for _ in range(4):
            sync()
            t0 = time.perf_counter()
            model.dvae.encode_decode(data.x, data.x0, sample=False)
            sync()
            times.append(time.perf_counter() - t0)
    return sorted(times[1:])[1]


def with_hidden(cfg: TrainConfig, hidden: int | None) -> TrainConfig:
    """The recipe with another recurrent width (None: its own)."""
    if hidden is None:
        return cfg
    return dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, hidden_dim=hidden))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto (cpu, and cuda if present)")
    ap.add_argument("--batch", default="64,256,1024", help="batch sizes, comma-separated")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: torch's)")
    ap.add_argument("--steps", type=int, default=10, help="timed steps per row")
    ap.add_argument("--config", type=Path, default=RECIPE, help="training config (the recipe)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead")
    ap.add_argument(
        "--json-lines",
        action="store_true",
        help="also print each row as a JSON line as soon as it is timed",
    )
    ap.add_argument(
        "--no-graph",
        action="store_true",
        help="on a GPU, time the eager step alone (default: eager and graphed)",
    )
    ap.add_argument("--hidden", default=None,
                    help="recurrent widths to time, comma-separated (default: the recipe's); "
                         "adds a regression-mode pass per width")  # fmt: skip
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = TrainConfig.from_dict(json.loads(args.config.read_text()), legacy=False)
    if args.device == "auto":
        devices = ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]
    else:
        devices = [args.device]
    rows = []
    batches = [int(b) for b in args.batch.split(",")]
    widths = [None] if args.hidden is None else [int(h) for h in args.hidden.split(",")]
    for hidden in widths:
        c = with_hidden(cfg, hidden)
        gflop = {b: step_gflop(c, b) for b in batches}
        for name in devices:
            device = torch.device(name)
            ceiling = matmul_rate(device)
            infer = inference_seconds(c, device) if hidden is not None else None
            modes = ["eager", "graph"] if name == "cuda" and not args.no_graph else ["eager"]
            for mode, batch in ((m, b) for m in modes for b in batches):
                s, failure = time_steps(c, device, batch, args.steps, graph=mode == "graph")
                rows.append(
                    {"device": name, "mode": mode if failure is None else "graph failed",
                     "failure": failure, "hidden": c.model.hidden_dim, "batch": batch,
                     "s_per_step": s, "steps_per_s": 1 / s, "windows_per_s": batch / s,
                     "gflop_per_step": gflop[batch], "gflop_per_s": gflop[batch] / s,
                     "matmul_gflop_per_s": ceiling, "regression_pass_s": infer}
                )  # fmt: skip
                if args.json_lines:  # as it comes (a GPU lent for minutes)
                    print(json.dumps(rows[-1]), flush=True)
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
    print("| device | step | hidden | batch | s/step | steps/s | windows/s | GFLOP/step "
          "| GFLOP/s (matmul alone) | regression pass, 18,000 frames (s) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        infer = "" if r["regression_pass_s"] is None else f"{r['regression_pass_s']:.3f}"
        print(
            f"| {r['device']} | {r['mode']} | {r['hidden']} | {r['batch']} | {r['s_per_step']:.4f} "
            f"| {r['steps_per_s']:.2f} | {r['windows_per_s']:,.0f} | {r['gflop_per_step']:.1f} "
            f"| {r['gflop_per_s']:.0f} ({r['matmul_gflop_per_s']:.0f}) | {infer} |"
        )
    return result


if __name__ == "__main__":
    main()
