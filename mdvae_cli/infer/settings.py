"""Settings of latent refinement and of the closed-form offset (``mdvae denoise --refine``,
``--offset`` and ``--outliers``): one dataclass that ``infer.refine`` and
``infer.closed_form`` both read."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mdvae_cli.errors import InputError

OUTLIER_DOF = 10.0  # Student-t degrees of freedom of `mdvae denoise --outliers` (docs/model.md)


@dataclass
class RefineConfig:
    """Latent refinement settings.

    steps: Adam steps per window (0 = the encoder's latents, with the closed-form offset
    alone when offset_std > 0); lr: Adam step size on the normalised
    latents and x0; lam: strength of the IG(lam/2, lam/2 * unit^2) prior on each noise variance,
    in pseudo-observations; rot_unit (rad) and trans_unit (m): the noise scales that prior
    centres on; batch_windows: windows refined together (memory bound, not a result change:
    every window's steps depend on that window alone); offset_std (rad): prior standard
    deviation each joint's slow rotation offset centres on (0 = no offset); offset_lam:
    strength of the IG(offset_lam/2, offset_lam/2 * offset_std^2) prior on each joint's
    offset variance, in pseudo-coefficients; offset_terms: how many cosines (1 = a constant
    offset per window); offset_decay: cosine k's prior scale is offset_decay^k times the
    joint's (faster terms are smaller: a smoothness prior; 0.85, the best on the val split
    with refinement steps and, for the shipped distilled networks, without, docs/model.md);
    trans_offset_std (m): the same for the root translation's slow offset, fitted with the
    rotations' when ``steps`` = 0 (the decoded translation drifts from the file's by ~4 cm on
    average within a window; refinement fits it through the latents instead); 0 = none;
    offset_iterations: rounds of the
    closed-form updates when ``steps`` = 0 (the offset on regression mode's output);
    outlier_dof: 0 = Gaussian noise with one variance per joint and window; > 0 = Student-t
    noise per frame and joint with this many degrees of freedom (a spike is down-weighted on its
    own frame instead of inflating its joint's variance; ``mdvae denoise --outliers``).
    """

    steps: int = 50
    lr: float = 0.1
    lam: float = 10.0
    rot_unit: float = 0.2
    trans_unit: float = 0.05
    batch_windows: int = 256
    offset_std: float = 0.03
    trans_offset_std: float = 0.03
    offset_terms: int = 10
    offset_lam: float = 3.0
    offset_decay: float = 0.85
    offset_iterations: int = 5
    outlier_dof: float = 0.0

    def __post_init__(self):
        if self.steps < 0:
            raise InputError(f"refinement steps must be >= 0, got {self.steps}")
        for name in ("lr", "lam", "rot_unit", "trans_unit"):
            if not getattr(self, name) > 0:
                raise InputError(f"refinement {name} must be > 0, got {getattr(self, name)}")
        if self.batch_windows < 1:
            raise InputError(f"refinement batch must be >= 1 window, got {self.batch_windows}")
        for name in ("offset_std", "trans_offset_std"):
            if not getattr(self, name) >= 0:
                raise InputError(f"refinement {name} must be >= 0, got {getattr(self, name)}")
        if not self.offset_lam > 0:
            raise InputError(f"refinement offset_lam must be > 0, got {self.offset_lam}")
        if not 0 < self.offset_decay <= 1:
            raise InputError(f"refinement offset_decay must be in (0, 1], got {self.offset_decay}")
        if self.offset_iterations < 1:
            raise InputError(
                f"refinement offset_iterations must be >= 1, got {self.offset_iterations}"
            )
        if not self.outlier_dof >= 0:
            raise InputError(f"refinement outlier_dof must be >= 0, got {self.outlier_dof}")
        if self.offset_terms < 1:
            raise InputError(f"refinement offset_terms must be >= 1, got {self.offset_terms}")

    @property
    def active(self) -> bool:
        """Whether these settings change regression mode's output at all (steps or offset)."""
        return self.steps > 0 or self.offset_std > 0 or self.trans_offset_std > 0

    def to_dict(self) -> dict:
        return asdict(self)
