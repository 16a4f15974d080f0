"""Unsupervised learned denoising (paper Sec. 4): inference networks and the ELBO of Eq. 12-15.

Observations of a window (B windows, T + 1 frames incl. frame 0):
  yn  (B, T+1, 138)  the noisy states, normalised with the prior's normaliser (canonical frame)
  y3d (B, T+1, 65, 3) the 22 joints + 43 virtual markers of M_beta(noisy parameters), metres
Generative model: x_t = decoder(x0, z_{1:t}) as in the prior (frozen), y3d_t ~ N(M(x_t), v_t)
with v_t,j,d ~ IG(lam/2, lam/2) in units of ``obs_unit`` metres (heavy-tailed Student-t for small
lam, nearly Gaussian with unit variance for large lam).
Inference networks (trained): encoder q_phi (initialised from the prior's), x0_predictor
q_omega(x0 | y_{0:T}) (Gaussian), noise_predictor q_gamma(v_t | z_{1:t}, y_t, x0) (Inverse-Gamma).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import torch
from torch import nn

from mdvae_cli.body.data import NUM_BODY_JOINTS
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.model.checkpoint import (
    float32_default,
    load_checkpoint,
    load_weights,
    save_checkpoint,
)
from mdvae_cli.model.config import ModelConfig, require_bool, require_int, require_number
from mdvae_cli.model.dvae import Encoder, Gaussian, mlp
from mdvae_cli.model.losses import gaussian_kl, inverse_gamma_expectations, inverse_gamma_kl
from mdvae_cli.model.prior_model import PriorModel, model_tensors
from mdvae_cli.model.state import state_to_params
from mdvae_cli.weights import default_weights


@dataclass
class DenoiserConfig:
    """Noise model and inference-network sizes.

    lam: Inverse-Gamma prior IG(lam/2, lam/2) on the observation variances.
    obs_unit: metres per observation unit (the scale at which v ~ 1 under the prior).
    hidden_dim: width of the x0 and noise predictors.
    velocity_window: frames of the local line fit that gives the noisy states' velocities
        (1 = plain finite differences, which turn per-frame noise into huge velocities).
    x0_window: the x0 predictor's base estimate is a least-squares line through the first
        ``x0_window`` noisy states evaluated at frame 0 (1 = the noisy first state itself).
    x0_bidirectional: the x0 predictor's GRU runs both ways (checkpoints from before this
        option); read at frame 0, the forward direction has seen one frame only, so new
        denoisers run the backward direction alone, at half the cost.
    input_window, input_order: the inference networks (encoder, x0 predictor) read the noisy
        motion after a Savitzky-Golay filter of this many frames and this degree (0 = raw);
        the likelihood always scores the raw observations. Per-frame noise read raw passes
        straight into z_t and the output jitters; read through the filter, the encoder sees
        the motion's trend and the ELBO still fits the unfiltered data.
    reads_holes: the networks also read which body joints of each frame are missing (a
        learned offset of their input per missing joint, :meth:`Denoiser.read_holes`); set
        when a fit trains on takes with holes (``fit-dataset --holes``).
    """

    lam: float = 10.0
    obs_unit: float = 0.08
    hidden_dim: int = 128
    velocity_window: int = 9
    x0_window: int = 9
    x0_bidirectional: bool = False
    input_window: int = 11
    input_order: int = 1
    reads_holes: bool = False

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError naming the first invalid setting (in ``mdvae fit-dataset``'s words)."""
        require_number("--lam", self.lam, 0.0, open_low=True)
        require_bool("x0_bidirectional", self.x0_bidirectional)
        require_bool("reads_holes", self.reads_holes)
        require_number("--obs-unit", self.obs_unit, 0.0, open_low=True)
        for name in ("hidden_dim", "velocity_window", "x0_window"):
            require_int(name, getattr(self, name), 1)
        require_int("--input-window", self.input_window, 0)
        if self.input_window > 1 and self.input_window % 2 == 0:
            raise InputError(
                f"--input-window must be 0 or an odd number of frames, got {self.input_window}"
            )
        require_int("input_order", self.input_order, 0)
        if self.input_window > 1 and not self.input_order < self.input_window:
            raise InputError(
                f"input filter degree must be below its window, got {self.input_order}"
            )

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, legacy: bool = True) -> DenoiserConfig:
        """``legacy``: as :meth:`ModelConfig.from_dict` (missing options predate them)."""
        names = {f.name for f in fields(cls)}
        if legacy:  # configs written before these options existed
            d = {"x0_bidirectional": True, "input_window": 0, **d}
        return cls(**{k: v for k, v in d.items() if k in names})


def line_start_weights(n: int) -> torch.Tensor:
    """Weights c with ``c @ y[:n]`` = the least-squares line through y_0..y_{n-1} at 0.  (n,)"""
    if n <= 1:
        return torch.ones(1)
    k = torch.arange(n, dtype=torch.float64)
    c = (2 * (2 * n - 1) - 6 * k) / (n * (n + 1))
    return c.float()


class X0Predictor(nn.Module):
    """q_omega(x0 | y_{0:T}) = N(mu, sigma): a GRU run backward over the window (its final
    state summarises y_{0:T}), residual on a base estimate (the noisy first state, or a line
    fitted through the first frames)."""

    def __init__(
        self, state_dim: int, hidden: int, base_window: int = 1, bidirectional: bool = False
    ):
        super().__init__()
        self.register_buffer("base_weights", line_start_weights(base_window), persistent=False)
        self.bidirectional = bidirectional
        self.rnn = nn.GRU(state_dim, hidden, batch_first=True, bidirectional=bidirectional)
        width = 2 * hidden if bidirectional else hidden
        self.head = mlp(width + state_dim, hidden, 2 * state_dim)
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)

    def forward(self, yn: torch.Tensor) -> Gaussian:
        """yn: (B, T+1, D) -> Gaussian over normalised x0, (B, D)"""
        if self.bidirectional:
            summary = self.rnn(yn)[0][:, 0]
        else:
            summary = self.rnn(yn.flip(1))[1][0]  # final state of the backward pass
        n = min(self.base_weights.shape[0], yn.shape[1])
        w = line_start_weights(n) if n < self.base_weights.shape[0] else self.base_weights
        w = w.to(yn)  # float32 as built; a caller's float64 default makes the rest float64
        base = torch.einsum("k,bkd->bd", w, yn[:, :n])
        delta, logvar = self.head(torch.cat([summary, base], dim=-1)).chunk(2, dim=-1)
        return Gaussian(base + delta, (logvar - 4.0).clamp(-12.0, 4.0))


class NoisePredictor(nn.Module):
    """q_gamma(v_t | z_{1:t}, y_t, x0) = IG(alpha, beta) per observation coordinate.

    It reads the decoder state h_t (a summary of x0 and z_{1:t}) and the observation y_t.
    """

    def __init__(self, hidden_dim: int, state_dim: int, obs_dim: int, width: int):
        super().__init__()
        self.head = mlp(hidden_dim + state_dim, width, 2 * obs_dim)
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)

    def forward(self, h: torch.Tensor, yn: torch.Tensor, lam: float):
        """h: (B, T+1, H), yn: (B, T+1, D) -> alpha, beta (B, T+1, obs_dim), both > 0.

        At zero output it returns the prior IG(lam/2, lam/2).
        """
        a, b = self.head(torch.cat([h, yn], dim=-1)).chunk(2, dim=-1)
        alpha = 1.0 + (lam / 2 - 1.0) * torch.exp(a.clamp(-8.0, 8.0))
        beta = (lam / 2) * torch.exp(b.clamp(-12.0, 12.0))
        return alpha, beta


class Denoiser(nn.Module):
    """The frozen prior (prior + decoder) with the trainable inference networks."""

    def __init__(self, prior: PriorModel, cfg: DenoiserConfig):
        super().__init__()
        self.cfg = cfg
        self.prior = prior
        for p in self.prior.parameters():
            p.requires_grad_(False)
        mc = prior.cfg
        self.encoder: Encoder = copy.deepcopy(prior.dvae.encoder)
        for p in self.encoder.parameters():
            p.requires_grad_(True)
        self.x0_predictor = X0Predictor(
            mc.state_dim, cfg.hidden_dim, cfg.x0_window, cfg.x0_bidirectional
        )
        self.noise_predictor = NoisePredictor(
            mc.hidden_dim, mc.state_dim, mc.obs_dim, cfg.hidden_dim
        )
        self.hole_reader: nn.Linear | None = None
        if cfg.reads_holes:
            self.add_hole_reader()

    def add_hole_reader(self) -> None:
        """Let the networks read the holes (``cfg.reads_holes``): a linear map from each
        frame's missing joints to an offset of its input, zero at first (the networks' output
        is unchanged until a fit on takes with holes trains it)."""
        self.cfg.reads_holes = True
        if self.hole_reader is None:
            reader = nn.Linear(NUM_BODY_JOINTS, self.prior.cfg.state_dim, bias=False)
            nn.init.zeros_(reader.weight)
            self.hole_reader = reader.to(next(self.encoder.parameters()).device)

    def read_holes(self, yn: torch.Tensor, obs_weight: torch.Tensor | None) -> torch.Tensor:
        """What the networks read: the normalised states, offset where joints are missing.

        yn: (B, T+1, D); obs_weight: (B, T+1, >= 22) 1 for observed, 0 for missing, body
        joints first (or None: nothing missing) -> (B, T+1, D)"""
        if self.hole_reader is None or obs_weight is None:
            return yn
        missing = 1.0 - obs_weight[..., :NUM_BODY_JOINTS].to(yn)
        return yn + self.hole_reader(missing)

    def trainable_parameters(self) -> list[nn.Parameter]:
        """phi, gamma, omega: encoder, noise predictor, x0 predictor (and the hole reader)."""
        return [p for m in self.network_modules().values() for p in m.parameters()]

    def network_modules(self) -> dict[str, nn.Module]:
        """The trained networks by checkpoint name (the hole reader where there is one)."""
        mods = {n: getattr(self, n) for n in ("encoder", "x0_predictor", "noise_predictor")}
        if self.hole_reader is not None:
            mods["hole_reader"] = self.hole_reader
        return mods

    def train(self, mode: bool = True) -> Denoiser:
        super().train(mode)
        self.prior.eval()  # the generative model stays fixed
        return self

    def infer(self, yn: torch.Tensor, sample: bool = False, generator=None, with_prior=True):
        """Posterior means (or samples) of x0 and z, and the decoded states.

        yn: (B, T+1, D) -> dict with x_hat (B, T+1, D) in state units, x_hat_n normalised,
        x0 posterior, z posterior, prior over z (None unless ``with_prior``: only the ELBO needs
        it), decoder states h (B, T+1, H)
        """
        dvae = self.prior.dvae
        q_x0 = self.x0_predictor(yn)
        x0n = q_x0.sample(generator) if sample else q_x0.mean
        x_mean, z, q_z, h = dvae.encode_decode(yn[:, 1:], x0n, sample, generator, self.encoder)
        p_z = dvae.prior(z, x0n) if with_prior else None
        h0 = dvae.decoder.init(x0n)[:, None]
        x_hat_n = torch.cat([x0n[:, None], x_mean], dim=1)
        return {
            "x_hat_n": x_hat_n,
            "x_hat": self.prior.normalizer.denormalize(x_hat_n),
            "q_x0": q_x0,
            "q_z": q_z,
            "p_z": p_z,
            "h": torch.cat([h0, h], dim=1),
        }

    def elbo(
        self,
        yn: torch.Tensor,
        y3d: torch.Tensor,
        betas: torch.Tensor,
        body: BodyModel,
        obs_weight: torch.Tensor | None = None,
        generator=None,
        seen: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Negative ELBO per frame (Eq. 12-15) with one Monte-Carlo sample of x0 and z.

        yn: (B, T+1, D); y3d: (B, T+1, 65, 3) metres; betas: (B, S);
        obs_weight: (B, T+1, 65) 1 for observed points, 0 for missing (or None); the networks
        read it too where they read holes (:meth:`read_holes`), unless ``seen`` (B, T+1, 22)
        says what they read instead (frames hidden from them that the likelihood scores).
        """
        yn = self.read_holes(yn, obs_weight if seen is None else seen)
        out = self.infer(yn, sample=True, generator=generator)
        B, T1 = yn.shape[:2]
        pred = observe(body, out["x_hat"], betas)
        sq = ((y3d - pred) / self.cfg.obs_unit) ** 2  # (B, T+1, 65, 3)
        alpha, beta = self.noise_predictor(out["h"], yn, self.cfg.lam)
        inv_v, log_v = inverse_gamma_expectations(alpha, beta)
        inv_v, log_v = inv_v.reshape(sq.shape), log_v.reshape(sq.shape)
        rec = 0.5 * (inv_v * sq + log_v)
        if obs_weight is not None:
            rec = rec * obs_weight[..., None]
        kl_z = gaussian_kl(out["q_z"].mean, out["q_z"].logvar, out["p_z"].mean, out["p_z"].logvar)
        kl_v = inverse_gamma_kl(alpha, beta, self.cfg.lam / 2, self.cfg.lam / 2)
        n = B * T1
        terms = {
            "rec": rec.sum() / n,
            "kl_z": kl_z.sum() / n,
            "kl_noise": kl_v.sum() / n,
            "err_cm": ((y3d - pred).norm(dim=-1).mean() * 100).detach(),
        }
        terms["loss"] = terms["rec"] + terms["kl_z"] + terms["kl_noise"]
        return terms


def observe(body: BodyModel, x: torch.Tensor, betas: torch.Tensor) -> torch.Tensor:
    """y3d = [joints, markers] of states.  x: (B, T, 138), betas: (B, S) -> (B, T, 65, 3)"""
    B, T = x.shape[:2]
    p = state_to_params(x.reshape(B * T, -1))
    out = body(p.root_orient, p.pose_body, p.trans, betas.repeat_interleave(T, 0))
    return torch.cat([out.joints, out.markers], dim=1).reshape(B, T, -1, 3)


def save_denoiser(path: Path, denoiser: Denoiser, meta: dict) -> None:
    """Write a denoiser checkpoint (its prior inside it) with ``meta`` beside the configs."""
    tensors = model_tensors(denoiser.prior, "prior/")
    for name, module in denoiser.network_modules().items():
        tensors.update(model_tensors(module, f"{name}/"))
    meta = {
        **meta,
        "model_config": denoiser.prior.cfg.to_dict(),
        "denoiser_config": denoiser.cfg.to_dict(),
        "kind": "mdvae-denoiser",
    }
    save_checkpoint(Path(path), tensors, meta)


def fit_on(prior: Path) -> str:
    """What makes a denoiser of a prior (a denoiser is fitted on one; commands that read a
    denoiser have no --prior)."""
    return f"fit a denoiser on it first with `mdvae fit-dataset NOISY --prior {prior} -o DENOISER`"


def load_denoiser(
    path: Path | str | None = None, *, keep_rng: bool = True
) -> tuple[Denoiser, dict]:
    """Load a denoiser checkpoint (file, or a fit-dataset folder's ``denoiser.npz``); None
    loads the weights shipped with the package. ``keep_rng``: torch's global random state
    is as it was (building the networks draws their first weights from it); training
    passes False, so that a seeded run draws what it always drew."""
    with torch.random.fork_rng(devices=[], enabled=keep_rng), float32_default():
        return _load_denoiser(path)


def _load_denoiser(path: Path | str | None) -> tuple[Denoiser, dict]:
    path = default_weights("denoiser") if path is None else Path(path)
    if path.is_dir():
        if not (path / "denoiser.npz").exists() and (path / "best.npz").exists():
            raise InputError(
                f"{path} is a train-prior run (a prior), not a denoiser: {fit_on(path)}"
            )
        path = path / "denoiser.npz"
    tensors, meta = load_checkpoint(path)
    if meta.get("kind") != "mdvae-denoiser" and "train_config" in meta:  # a train-prior file
        raise InputError(f"{path} is not a denoiser checkpoint but a prior: {fit_on(path)}")
    if meta.get("kind") != "mdvae-denoiser":
        raise InputError(f"{path} is not a denoiser checkpoint (train one with fit-dataset)")
    prior = PriorModel(ModelConfig.from_dict(meta["model_config"]))
    denoiser = Denoiser(prior, DenoiserConfig.from_dict(meta["denoiser_config"]))
    for prefix, module in (
        ("prior/", denoiser.prior),
        *((f"{name}/", m) for name, m in denoiser.network_modules().items()),
    ):
        state = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
        load_weights(module, state, path)
    return denoiser.eval(), meta
