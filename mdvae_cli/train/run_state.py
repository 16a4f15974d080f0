"""What a resumable training run keeps beside its weights: the optimiser's state and torch's
generators, as flat tensors for :func:`mdvae_cli.model.checkpoint.save_checkpoint`."""

from __future__ import annotations

import functools

import torch


def optimizer_to_tensors(opt: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict]:
    """Split an optimizer state dict into flat tensors and JSON-able groups. A graphed
    step's Adam (``capturable``, its rate a device tensor: ``train.prior_step``) is saved as
    a plain one, its step counts on the CPU, so that any device resumes it."""
    sd = opt.state_dict()
    tensors = {}
    for idx, state in sd["state"].items():
        for key, value in state.items():
            value = torch.as_tensor(value)
            tensors[f"optim/{idx}/{key}"] = value.cpu() if key == "step" else value
    groups = []
    for group in sd["param_groups"]:
        group = dict(group)
        if isinstance(group.get("lr"), torch.Tensor):
            group["lr"] = float(group["lr"])
        if group.get("capturable"):
            group["capturable"] = False
        groups.append(group)
    return tensors, {"param_groups": groups}


def optimizer_from_tensors(tensors: dict[str, torch.Tensor], groups: dict) -> dict:
    """Inverse of :func:`optimizer_to_tensors`: a state dict for ``load_state_dict``."""
    state: dict[int, dict] = {}
    for name, value in tensors.items():
        if not name.startswith("optim/"):
            continue
        _, idx, key = name.split("/", 2)
        state.setdefault(int(idx), {})[key] = value
    return {"state": state, "param_groups": groups["param_groups"]}


def rng_tensors(device: torch.device | None) -> dict[str, torch.Tensor]:
    """The states of torch's generators (CPU, and the GPU's when training on one)."""
    out = {"rng/cpu": torch.get_rng_state()}
    if device is not None and device.type == "cuda":
        out["rng/cuda"] = torch.cuda.get_rng_state(device)
    return out


def restore_rng(tensors: dict[str, torch.Tensor], device: torch.device) -> None:
    """Inverse of :func:`rng_tensors`; a checkpoint without them (older runs) leaves the
    generators as seeded."""
    if "rng/cpu" in tensors:
        torch.set_rng_state(tensors["rng/cpu"])
    if "rng/cuda" in tensors and device.type == "cuda":
        torch.cuda.set_rng_state(tensors["rng/cuda"], device)


def seed_streams(seed: int, device: torch.device) -> None:
    """Seed torch's CPU generator and, for a run on a GPU, every CUDA device's (as
    ``torch.manual_seed`` does); a run on the CPU leaves the GPUs' generators alone (not even
    a seed queued for when CUDA starts)."""
    torch.default_generator.manual_seed(seed)
    if device.type == "cuda":
        torch.cuda.manual_seed_all(seed)


def seeded_run(fn):
    """``fn(cfg, ...)``, a training run, started with torch's generators seeded with
    ``cfg.seed`` (:func:`seed_streams`: the GPUs' too where it runs on one) and leaving the
    caller's as they were: the CPU's and, where CUDA is in use (by the run, or already by the
    caller), every CUDA device's. ``cfg`` is validated first."""

    @functools.wraps(fn)
    def run(cfg, *args, **kwargs):
        cfg.validate()
        gpu = torch.cuda.is_available() and cfg.device != "cpu"
        started = torch.cuda.is_available() and torch.cuda.is_initialized()
        devices = list(range(torch.cuda.device_count())) if gpu or started else []
        with torch.random.fork_rng(devices=devices):
            seed_streams(cfg.seed, torch.device("cuda" if gpu else "cpu"))
            return fn(cfg, *args, **kwargs)

    return run
