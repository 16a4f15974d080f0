"""The settings of a prior training run (``mdvae train-prior``), saved as ``config.json``."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from mdvae_cli.errors import InputError
from mdvae_cli.model.config import (
    ModelConfig,
    check_config_keys,
    require_bool,
    require_int,
    require_number,
    require_seed,
)
from mdvae_cli.train.guards import check_device

#: what ``--train-only`` may name
TRAINABLE = ("all", "encoder", "prior")


@dataclass
class TrainConfig:
    """Everything that defines a prior training run (saved as ``config.json``)."""

    data: list[str] = field(default_factory=list)
    split_file: str | None = None
    window: int = 60
    stride: int = 10
    batch_size: int = 64
    epochs: int = 40
    lr: float = 1e-3
    lr_final: float = 1e-4
    #: steps of linear learning-rate warm-up before the cosine decay (0 = none; large batches
    #: with a large rate need a few)
    lr_warmup_steps: int = 0
    kl_warmup_steps: int = 1500
    kl_max: float = 1.0
    recon_weight: float = 1.0
    velocity_weight: float = 1.0
    body_weight: float = 0.1
    body_vertices: int = 256
    body_frame_stride: int = 4
    velocity_std_scale: float = 1.0
    grad_clip: float = 5.0
    seed: int = 0
    body_model: str | None = None
    device: str = "auto"
    max_val_windows: int = 512
    init_from: str | None = None
    #: "all" trains prior, decoder and encoder; "encoder" keeps the generative model (prior and
    #: decoder, hence sampling) fixed and trains only the inference network, e.g. under a
    #: sharper reconstruction weight (closing the amortisation gap of a trained prior)
    train_only: str = "all"
    #: also train on every training motion's left-right mirror image (twice the windows)
    mirror_augment: bool = False
    #: play speeds every training motion is also used at (time-warp augmentation; 1.0 = as
    #: captured, e.g. [0.8, 1.0, 1.25]); validation stays at 1.0
    speeds: list[float] = field(default_factory=lambda: [1.0])
    #: train on a seeded subset of whole training files holding this share of the frames (the
    #: data-scaling runs); 1.0 = all
    data_fraction: float = 1.0
    #: the split-file lists whose windows choose the best checkpoint (e.g. ["val", "unseen_val"])
    val_splits: list[str] = field(default_factory=lambda: ["val"])
    #: validate and checkpoint every this many epochs (and at the end, or where a budget stops
    #: the run): a small share of the data on a GPU makes epochs of seconds
    val_every_epochs: int = 1
    #: on a GPU, capture the step as a CUDA graph and replay it (train.prior_step); no effect
    #: on a CPU or under DDP
    cuda_graph: bool = True
    model: ModelConfig = field(default_factory=ModelConfig)

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError naming the first invalid setting (its ``mdvae train-prior`` option, or
        its config key where it has none). Run again after changing fields."""
        for name, option, low in (
            ("window", "--window", 1),
            ("stride", "--stride", 1),
            ("batch_size", "--batch-size", 1),
            ("epochs", "--epochs", 1),
            ("kl_warmup_steps", "--kl-warmup", 0),
            ("lr_warmup_steps", "--lr-warmup", 0),
            ("body_vertices", "body_vertices", 0),
            ("body_frame_stride", "body_frame_stride", 1),
            ("max_val_windows", "max_val_windows", 1),
            ("val_every_epochs", "--val-every", 1),
        ):
            require_int(option, getattr(self, name), low)
        require_seed("--seed", self.seed)
        for name, option, low, open_low in (
            ("lr", "--lr", 0.0, True),
            ("lr_final", "lr_final", 0.0, False),
            ("kl_max", "--kl-max", 0.0, False),
            ("recon_weight", "--recon-weight", 0.0, True),
            ("velocity_weight", "--velocity-weight", 0.0, False),
            ("body_weight", "--body-weight", 0.0, False),
            ("velocity_std_scale", "--velocity-std-scale", 0.0, True),
            ("grad_clip", "grad_clip", 0.0, True),
        ):
            require_number(option, getattr(self, name), low, open_low=open_low)
        if self.train_only not in TRAINABLE:  # the CLI's --train-only is a choice already
            raise InputError(
                f"train_only must be one of {', '.join(TRAINABLE)}, got {self.train_only!r}"
            )
        require_bool("--mirror-augment", self.mirror_augment)
        require_bool("--cuda-graph", self.cuda_graph)
        if not isinstance(self.speeds, (list, tuple)) or not self.speeds:
            raise InputError(f"--speeds must be a list of play speeds, got {self.speeds!r}")
        for speed in self.speeds:
            require_number("--speeds", speed, 0.25, 4.0)
        require_number("--data-fraction", self.data_fraction, 0.0, 1.0, open_low=True)
        if not isinstance(self.val_splits, (list, tuple)) or not all(
            isinstance(v, str) for v in self.val_splits
        ):
            raise InputError(f"--val-split must name split lists, got {self.val_splits!r}")
        if self.train_only != "all" and not self.init_from:
            raise InputError(
                f"--train-only {self.train_only} trains part of a trained prior: give --init-from"
            )
        check_device(self.device)
        self.model.validate()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["model"] = self.model.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict, legacy: bool = True, source: str = "config") -> TrainConfig:
        """Settings from a JSON object. InputError (starting with ``source``) for an unknown
        key, a value of the wrong kind or out of range. ``legacy``: ``d`` is a run's own
        config.json (see :meth:`ModelConfig.from_dict`; nested keys it has no more are old
        options, not mistakes)."""
        check_config_keys(cls, d, source, nested=not legacy)
        d = dict(d)
        try:
            d["model"] = ModelConfig.from_dict(d.get("model", {}), legacy)
            return cls(**d)
        except (ValueError, TypeError) as exc:
            raise InputError(f"{source} is unreadable ({exc})") from None
