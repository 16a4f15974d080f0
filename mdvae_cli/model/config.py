"""Model hyper-parameters: one dataclass, saved as JSON beside every checkpoint; and the checks
every settings dataclass (model, training, fitting, denoiser) runs on its values."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, is_dataclass

from mdvae_cli.errors import InputError
from mdvae_cli.model.state import STATE_DIM


def require_number(
    name: str,
    value,
    low: float | None = None,
    high: float | None = None,
    open_low: bool = False,
) -> None:
    """InputError unless ``value`` is a finite number within [low, high] (``open_low``: > low).

    ``name`` is what the user calls the setting (``--lam``, or a config key)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (low is None or value > low or (value == low and not open_low))
    ok = ok and (high is None or value <= high)
    if not ok:
        if low is not None and high is not None:
            bounds = f" in {'(' if open_low else '['}{low:g}, {high:g}]"
        elif low is not None:
            bounds = f" {'>' if open_low else '>='} {low:g}"
        else:
            bounds = ""
        raise InputError(f"{name} must be a finite number{bounds}, got {value!r}")


def require_bool(name: str, value) -> None:
    """InputError unless ``value`` is true or false (not a string such as "no")."""
    if not isinstance(value, bool):
        raise InputError(f"{name} must be true or false, got {value!r}")


def require_int(name: str, value, low: int) -> None:
    """InputError unless ``value`` is a whole number >= ``low``."""
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
        raise InputError(f"{name} must be a whole number >= {low}, got {value!r}")


#: the largest random seed: torch's generators take 64-bit seeds
MAX_SEED = 2**63 - 1


def require_seed(name: str, value) -> None:
    """InputError unless ``value`` is a whole number in 0..MAX_SEED."""
    require_int(name, value, 0)
    if value > MAX_SEED:
        raise InputError(f"{name} must be at most {MAX_SEED}, got {value}")


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

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError naming the first invalid size (every width >= 1)."""
        for name, option in (
            ("state_dim", "state_dim"),
            ("latent_dim", "--latent-dim"),
            ("hidden_dim", "--hidden-dim"),
            ("mlp_dim", "mlp_dim"),
            ("obs_dim", "obs_dim"),
        ):
            require_int(option, getattr(self, name), 1)
        for name in ("decoder_z_skip", "encoder_reads_decoder", "encoder_x_skip"):
            require_bool(name, getattr(self, name))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, legacy: bool = True) -> ModelConfig:
        """``legacy``: ``d`` was saved by mdvae, and an option it lacks predates that option (it
        was off then); otherwise (a config a user wrote) a missing option takes its default."""
        names = {f.name for f in fields(cls)}
        if legacy:  # configs written before these options existed
            old = {"decoder_z_skip": False, "encoder_reads_decoder": False, "encoder_x_skip": False}
            d = {**old, **d}
        return cls(**{k: v for k, v in d.items() if k in names})


def check_config_keys(cls, d, source: str, nested: bool = True, where: str = "") -> None:
    """InputError naming the first key of config ``d`` that the settings dataclass ``cls``
    lacks (``nested``: in its sub-configs too), or whose value is not of its JSON kind:
    sub-configs are objects, paths strings (or null), ``data`` a list of strings; numbers are
    checked by ``validate``. ``source`` starts every message (e.g. "config runs/a.json")."""
    if not isinstance(d, dict):
        what = f'"{where[:-1]}"' if where else "it"
        raise InputError(f"{source}: {what} must be a JSON object {{key: value, ...}}")
    known = {f.name: f for f in fields(cls)}
    for key, value in d.items():
        f = known.get(key)
        if f is None:
            if not nested and where:
                continue
            raise InputError(
                f'{source}: unknown key "{where}{key}" (a run\'s config.json lists the keys)'
            )
        if is_dataclass(f.default_factory):
            check_config_keys(f.default_factory, value, source, nested, f"{where}{key}.")
        elif f.type in ("str", "str | None") and not (
            isinstance(value, str) or (value is None and f.type == "str | None")
        ):
            kind = "a string or null" if f.type == "str | None" else "a string"
            raise InputError(f'{source}: "{where}{key}" must be {kind}, got {value!r}')
        elif f.type == "list[str]" and not (
            isinstance(value, list) and all(isinstance(v, str) for v in value)
        ):
            raise InputError(f'{source}: "{where}{key}" must be a list of paths, got {value!r}')
