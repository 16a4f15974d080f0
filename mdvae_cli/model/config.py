"""Model hyper-parameters: one dataclass, saved as JSON beside every checkpoint."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from mdvae_cli.motion.state import STATE_DIM


@dataclass
class ModelConfig:
    """Sizes of the Motion-DVAE networks (see docs/model.md for the reasoning).

    state_dim: x_t width (138). latent_dim: z_t width. hidden_dim: every recurrent state.
    mlp_dim: width of the output heads. obs_dim: y3d width (22 joints + 43 markers) x 3.
    """

    state_dim: int = STATE_DIM
    latent_dim: int = 32
    hidden_dim: int = 128
    mlp_dim: int = 256
    obs_dim: int = (22 + 43) * 3

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})
