"""Model hyper-parameters: one dataclass, saved as JSON beside every checkpoint."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from mdvae_cli.motion.state import STATE_DIM


@dataclass
class ModelConfig:
    """Sizes of the Motion-DVAE networks (see docs/model.md for the reasoning).

    state_dim: x_t width (138). latent_dim: z_t width. hidden_dim: every recurrent state.
    mlp_dim: width of the output heads. obs_dim: y3d width (22 joints + 43 markers) x 3.
    decoder_z_skip: the decoder's output head reads z_t beside the recurrent state h_t
    (mu_x = x0 + MLP([h_t, z_t])); checkpoints from before this option read h_t only.
    encoder_reads_decoder: the encoder's head also reads the decoder's state after z_{1:t-1},
    i.e. what the decoder already knows when z_t arrives (still q(z_t | z_{1:t-1}, x_{t:T}, x0)).
    encoder_x_skip: the encoder's head also reads x_t itself, not only the backward summary of
    x_{t:T} (a 128-wide summary cannot carry a 138-wide state exactly).
    """

    state_dim: int = STATE_DIM
    latent_dim: int = 32
    hidden_dim: int = 128
    mlp_dim: int = 256
    obs_dim: int = (22 + 43) * 3
    decoder_z_skip: bool = True
    encoder_reads_decoder: bool = True
    encoder_x_skip: bool = True

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        names = {f.name for f in fields(cls)}
        # configs written before these options existed
        old = {"decoder_z_skip": False, "encoder_reads_decoder": False, "encoder_x_skip": False}
        d = {**old, **d}
        return cls(**{k: v for k, v in d.items() if k in names})
