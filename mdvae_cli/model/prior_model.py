"""The unit a prior checkpoint stores: Motion-DVAE + state normaliser + its config."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

from mdvae_cli.errors import InputError
from mdvae_cli.model.checkpoint import float32_default, load_checkpoint, load_weights
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.dvae import MotionDVAE
from mdvae_cli.model.normalizer import Normalizer


class PriorModel(nn.Module):
    """Motion-DVAE networks plus the normaliser of the states they were trained on."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.dvae = MotionDVAE(cfg)
        self.normalizer = Normalizer(cfg.state_dim)

    @torch.no_grad()
    def sample(
        self,
        x0: torch.Tensor,
        num_frames: int,
        generator=None,
        temperature: float = 1.0,
        particles: int = 1,
        log_weight: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Prior samples in state units.  x0: (B, D) canonical state -> (B, T, D).

        log_weight: optional constraint on the decoded states, (x_t, x_{t-1}) each (B, M, D)
        in state units -> (B, M) log-weights, with ``particles`` = M prior samples run side by
        side (see ``MotionDVAE.sample``).
        """
        x0n = self.normalizer.normalize(x0)
        weigh = None
        if log_weight is not None:
            denorm = self.normalizer.denormalize
            weigh = lambda xn, prev: log_weight(denorm(xn), denorm(prev))  # noqa: E731
        x = self.dvae.sample(x0n, num_frames, generator, temperature, particles, weigh)
        return self.normalizer.denormalize(x)


def model_tensors(model: nn.Module, prefix: str = "model/") -> dict[str, torch.Tensor]:
    return {prefix + k: v for k, v in model.state_dict().items()}


def load_prior(path: Path | str, *, keep_rng: bool = True) -> tuple[PriorModel, dict]:
    """Load a prior from a checkpoint file (``*.npz`` + ``*.json``) or a training run folder
    (its ``best.npz``). Returns the model in eval mode and the checkpoint metadata.
    ``keep_rng``: as ``model.denoiser.load_denoiser``'s."""
    with torch.random.fork_rng(devices=[], enabled=keep_rng), float32_default():
        return _load_prior(path)


def _load_prior(path: Path | str) -> tuple[PriorModel, dict]:
    path = Path(path)
    if path.is_dir():
        if not (path / "best.npz").exists() and (path / "denoiser.npz").exists():
            raise InputError(f"{path} is a denoiser (fit-dataset) folder, not a prior run")
        path = path / "best.npz"
    tensors, meta = load_checkpoint(path)
    if meta.get("kind") == "mdvae-denoiser":
        raise InputError(
            f"{path} is a denoiser (fit-dataset), not a prior: pass it as --denoiser, or as "
            "fit-dataset's --init-from"
        )
    if "model_config" not in meta:
        raise InputError(f"{path} is not a Motion-DVAE prior checkpoint (no model_config)")
    model = PriorModel(ModelConfig.from_dict(meta["model_config"]))
    state = {k[len("model/") :]: v for k, v in tensors.items() if k.startswith("model/")}
    load_weights(model, state, path)
    return model.eval(), meta


def widen_state(source: dict, target: dict) -> dict:
    """``source`` tensors fitted into ``target``'s shapes: equal shapes are copied; a weight
    matrix with extra input columns gets the source in its leading columns and zeros after
    them, so the widened network computes exactly what the source did."""
    out = {}
    for key, t in target.items():
        s = source.get(key)
        if s is None:
            raise ValueError(f"the checkpoint has no {key}")
        if s.shape == t.shape:
            out[key] = s.clone()
        elif s.ndim == 2 and t.ndim == 2 and s.shape[0] == t.shape[0] and s.shape[1] < t.shape[1]:
            w = torch.zeros_like(t)
            w[:, : s.shape[1]] = s
            out[key] = w
        else:
            raise ValueError(f"{key} has shape {tuple(s.shape)}, this network {tuple(t.shape)}")
    return out
