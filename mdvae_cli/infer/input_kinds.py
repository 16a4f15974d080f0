"""``mdvae denoise``'s settings per kind of input: mocap files, and the estimates of video pose
pipelines, whose errors differ (docs/model.md, "Denoising video estimates").

The table is the one place to re-tune when the shipped weights change: each row gives the values
that ``mdvae denoise`` uses for an input of that kind unless an option overrides them. The
``video`` row was chosen on val clips with ``mdvae add-noise --preset video``
(``benchmarks/video_table.py --tune``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mdvae_cli.errors import InputError
from mdvae_cli.infer.settings import RefineConfig


@dataclass(frozen=True)
class KindSettings:
    """Denoise defaults for one kind of input.

    lam: the paper's lambda, the Student-t degrees of freedom of the observation noise per
        frame and joint (small: heavy tails, so flips and spikes are down-weighted where they
        happen); 0 = Gaussian noise per joint and window.
    offset_std: scale (rad) of each joint's slow rotation offset (``--refine-offset``).
    trans_offset_std: scale (m) of the root translation's slow offset (``--trans-offset``).
    offset_terms: cosines in each window's slow offset (fewer: a slower offset).
    rot_unit, trans_unit: the noise levels (rad, m) the noise prior centres on.
    blend_fast: whether ``--blend`` also puts back the fast band of what the noise does not
        explain (a video tracker's jitter is not white: its fast band would come back as jitter);
        when not, the fast band still comes back where it is far beyond the noise
        (``noise_blend.GONE_MARGIN``: where the denoiser went wrong).
    feet_as_came: whether the foot lock keeps feet that read clean as they came
        (``FootLockConfig.clean_jitter``; a video tracker's feet can read clean and still
        jitter: they are smoothed as the lock's goal whatever their jitter).
    smooth_s: the standard deviation (seconds) of a Gaussian over the result, after the foot
        lock, at its full on a take whose input reads noisy and none on one that reads clean
        (``denoise_settings.smoothing_share``); 0: none. The networks were fitted to mocap
        noise; a video tracker's jitter comes through their fast band (``--smooth``).
    """

    lam: float = 0.0
    offset_std: float = 0.03
    trans_offset_std: float = 0.03
    offset_terms: int = 10
    rot_unit: float = 0.2
    trans_unit: float = 0.05
    blend_fast: bool = True
    feet_as_came: bool = True
    smooth_s: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)


#: input kind -> its settings ("mocap": AMASS-style and imported files; "video": the outputs of
#: video pose pipelines, ``motion.load_any``)
INPUT_KINDS: dict[str, KindSettings] = {
    "mocap": KindSettings(),
    # val clips, --preset video (benchmarks/video_table.py --tune; docs/model.md): Student-t
    # noise cuts the acceleration error by 17 % and foot skate by 17 % for +4 % MPJPE; lambda
    # 3, 5 and 10 score alike, 10 is --outliers. The blend's slow band only: on 40 test clips
    # with --preset video, MPJPE 10.05 -> 8.98 cm for acceleration error 6.0 -> 7.1 m/s^2 (both
    # bands: 9.06 cm, 27.8 m/s^2; the fast band still comes back where the denoiser went
    # wrong, noise_blend.GONE_MARGIN). The result smoothed over 0.05 s (1.5 frames at 30 Hz),
    # as far as the input reads noisy: on 32 val clips acceleration error 7.16 -> 5.68 m/s^2,
    # MPJPE 9.22 -> 9.19 cm; on 64 test / unseen_test clips 7.64 -> 5.16 / 10.74 -> 6.37 for
    # MPJPE 8.89 -> 8.86 / 9.13 -> 9.13 (0.067 s: 4.68 / 5.67 for 8.84 / 9.14)
    "video": KindSettings(lam=10.0, blend_fast=False, feet_as_came=False, smooth_s=0.05),
}


def kind_settings(kind: str) -> KindSettings:
    """The settings row of an input kind; InputError for an unknown kind."""
    if kind not in INPUT_KINDS:
        raise InputError(f"unknown input kind {kind!r} (known: {', '.join(INPUT_KINDS)})")
    return INPUT_KINDS[kind]


def refine_config(
    kind: str,
    *,
    steps: int = 0,
    lr: float = 0.1,
    offset: bool = True,
    lam: float | None = None,
    offset_std: float | None = None,
    trans_offset_std: float | None = None,
) -> tuple[RefineConfig | None, dict]:
    """The refinement / offset settings ``mdvae denoise`` uses for an input of ``kind``: the
    kind's row, with every argument that is not None taking precedence.

    -> (the RefineConfig, None for the plain forward pass (no offset, no steps); the settings
    as a dict, with their source: {"input_kind", "lam", "offset_std", ...})
    """
    row = kind_settings(kind)
    lam = row.lam if lam is None else float(lam)
    offset_std = row.offset_std if offset_std is None else float(offset_std)
    trans = row.trans_offset_std if trans_offset_std is None else float(trans_offset_std)
    chosen = {
        "input_kind": kind,
        "lam": lam,
        "offset": offset,
        "offset_std": offset_std,
        "trans_offset_std": trans,
        "offset_terms": row.offset_terms,
    }
    if not (steps or offset):
        return None, chosen
    cfg = RefineConfig(
        steps=steps,
        lr=lr,
        offset_std=offset_std,
        trans_offset_std=trans,
        offset_terms=row.offset_terms,
        rot_unit=row.rot_unit,
        trans_unit=row.trans_unit,
        outlier_dof=lam,
    )
    return cfg, chosen
