"""Every choice ``mdvae denoise`` makes, in one place: :class:`DenoiseSettings` (its defaults
are the command's) and :func:`denoise`, which applies them to motions as the command does.

The command builds a ``DenoiseSettings`` from its options; a Python user builds one directly:

    clean = denoise(motions, DenoiseSettings())                       # the command's default
    paper = denoise(motions, DenoiseSettings(offset=False))           # the paper's regression mode
    best = denoise(motions, DenoiseSettings(refine_steps=50, mirror=True))
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.filters import gaussian_filter_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig, lock_motions
from mdvae_cli.infer.fill import TAKE_NOISE_RAD, fill_holes
from mdvae_cli.infer.fill_choices import DEFAULT_FILL, FILLS, fill_for
from mdvae_cli.infer.input_kinds import kind_settings, refine_config
from mdvae_cli.infer.loop import which_loop
from mdvae_cli.infer.noise_blend import BlendReport, noise_level
from mdvae_cli.infer.rest_pose import keep_rest_frames
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.infer.time_pieces import (
    SIDE_BY_SIDE_PIECES,
    SIDE_BY_SIDE_REFINED,
    denoise_in_pieces,
)
from mdvae_cli.model.checkpoint import float32_default
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.motion.motion import Motion, check_motions, unshared

FEET = ("lock", "off")


@dataclass(frozen=True)
class DenoiseSettings:
    """What to do to a motion (``mdvae denoise --help`` explains each option).

    input_kind: "mocap" or "video" (the settings row the offset and refinement start from;
    the command picks it from the file); refine_steps, refine_lr: ``--refine N``,
    ``--refine-lr``; offset: the closed-form slow offset (False with refine_steps = 0 is the
    paper's regression mode untouched: no offset, blend or guard); lam, offset_std,
    trans_offset_std: override the kind's row (None keeps it); blend: put back what the
    input's own noise does not explain; guard: fall back to the smoothed input where the
    output moved further than the noise explains; feet: "lock" or "off"; loop: True / False,
    or None to detect cycles; mirror: average with the mirror image's result;
    optimize_steps, lr, seed: optimisation mode; window, overlap: the windows (30 Hz frames);
    rest_pose: leading rest-pose frames (an exporter's T-pose frame 0) kept as they came;
    fill: what the input's holes (``joint_mask`` False: missing frames and joints) become
    (``infer.fill.FILLS``); "off" leaves them as the input's values as they came;
    smooth_s: the Gaussian (seconds) over the result after the foot lock (None: the kind's
    row, ``KindSettings.smooth_s``; 0: none).
    """

    input_kind: str = "mocap"
    refine_steps: int = 0
    refine_lr: float = 0.1
    offset: bool = True
    lam: float | None = None
    offset_std: float | None = None
    trans_offset_std: float | None = None
    blend: bool = True
    guard: bool = False
    feet: str = "lock"
    loop: bool | None = None
    mirror: bool = False
    optimize_steps: int = 0
    lr: float = 3e-4
    seed: int = 0
    window: int = 60
    overlap: int = 15
    rest_pose: bool = True
    fill: str = DEFAULT_FILL
    smooth_s: float | None = None

    def __post_init__(self) -> None:
        if self.feet not in FEET:
            raise InputError(f"feet must be one of {', '.join(FEET)}, got {self.feet!r}")
        if self.fill not in FILLS:
            raise InputError(f"fill must be one of {', '.join(FILLS)}, got {self.fill!r}")
        if not 0 <= self.overlap < self.window:
            raise InputError(
                f"the overlap ({self.overlap}) must be smaller than the window ({self.window})"
            )
        if self.refine_steps < 0 or self.optimize_steps < 0:
            raise InputError("refine_steps and optimize_steps must be >= 0")
        if self.smooth_s is not None and not self.smooth_s >= 0:
            raise InputError(f"smooth_s must be >= 0 seconds, got {self.smooth_s}")

    def refine(self) -> RefineConfig | None:
        """The offset / refinement settings (None: the paper's plain forward pass)."""
        cfg, _ = self._refine_config()
        return cfg

    def _refine_config(self) -> tuple[RefineConfig | None, dict]:
        return refine_config(
            self.input_kind, steps=self.refine_steps, lr=self.refine_lr, offset=self.offset,
            lam=self.lam, offset_std=self.offset_std, trans_offset_std=self.trans_offset_std,
        )  # fmt: skip

    def refine_row(self) -> tuple[RefineConfig | None, dict]:
        """:meth:`refine` and the settings row it came from, with :meth:`smoothing` (for
        reports)."""
        cfg, chosen = self._refine_config()
        return cfg, {**chosen, "smooth_s": self.smoothing()}

    def smoothing(self) -> float:
        """The seconds of the Gaussian over the result (0: none; none in the paper's mode)."""
        if self.untouched:
            return 0.0
        return kind_settings(self.input_kind).smooth_s if self.smooth_s is None else self.smooth_s

    @property
    def untouched(self) -> bool:
        """The paper's regression mode: no offset, no refinement, so no blend and no guard."""
        return self.refine() is None

    @property
    def mode(self) -> str:
        """What runs after the networks' one pass: "optimization", "refinement",
        "regression+offset" or "regression" (the paper's mode untouched)."""
        if self.optimize_steps:
            return "optimization"
        if self.refine_steps:
            return "refinement"
        return "regression+offset" if self.offset else "regression"

    def to_dict(self) -> dict:
        return asdict(self)


def loops_of(motions: list[Motion], settings: DenoiseSettings) -> list[bool]:
    """Which motions to denoise as cycles: the setting, or each motion's own ends."""
    if settings.loop is not None:
        return [settings.loop] * len(motions)
    return which_loop(motions)


@float32_default()
def denoise(
    motions: list[Motion],
    settings: DenoiseSettings | None = None,
    denoiser: Denoiser | Path | str | None = None,
    body: BodyModel | BodyModelData | Path | str | None = None,
    *,
    loops: list[bool] | None = None,
    progress: Callable[[dict], None] | None = None,
    on_fallback: Callable[[int, float, float], None] | None = None,
    on_blend: Callable[[int, BlendReport], None] | None = None,
    on_smooth: Callable[[int, float], None] | None = None,
) -> list[Motion]:
    """Denoise motions as ``mdvae denoise`` does with ``settings`` (default: its defaults).

    denoiser / body: None loads the shipped weights / the built-in body, a path the
    checkpoint (or run folder) / body-model file; a ``BodyModelData`` is wrapped. ``loops``: which
    motions are cycles (None: :func:`loops_of`). Optimisation mode fine-tunes a copy of the
    denoiser, never the one passed. The callbacks: see ``infer.denoise.denoise_motions``;
    ``on_smooth(motion index, seconds)``: the Gaussian each result was smoothed with
    (:func:`smoothed`; 0: none).
    A take longer than 1.5 ``infer.time_pieces.PIECE_FRAMES`` frames that is no cycle is
    denoised a piece of time at a time and joined, its foot lock then run on the whole of it
    (memory flat in the take's length; not in optimisation mode, whose networks adapt to all
    of the motions at once). It runs with torch's default dtype float32 (as it was after).
    """
    import copy

    motions = check_motions(motions)
    settings = settings or DenoiseSettings()
    if not isinstance(denoiser, Denoiser):  # None: the shipped weights; else a path
        from mdvae_cli.model.denoiser import load_denoiser

        denoiser, _ = load_denoiser(denoiser)
    if not isinstance(body, BodyModel):  # None: the built-in body; a path; BodyModelData
        from mdvae_cli.body.formats import load_body_model

        body = BodyModel(body if isinstance(body, BodyModelData) else load_body_model(body))
    refine = settings.refine()
    model = copy.deepcopy(denoiser) if settings.optimize_steps else denoiser

    def run(ms, lps, progress_, on_fallback_, on_blend_, piece=False) -> list[Motion]:
        return denoise_motions(
            ms,
            model,
            body,
            settings.window,
            settings.window - settings.overlap,
            optimize_steps=settings.optimize_steps,
            lr=settings.lr,
            seed=settings.seed,
            progress=progress_,
            refine=refine,
            mirror=settings.mirror,
            guard=settings.guard and refine is not None,
            on_fallback=on_fallback_,
            loops=lps,
            feet=None if piece else lock_config(settings),  # a piece's lock: on the whole
            blend=settings.blend and refine is not None,
            on_blend=on_blend_,
            blend_fast=kind_settings(settings.input_kind).blend_fast,
            fill=fill_for(settings.fill, denoiser.cfg.reads_holes),
        )

    def run_all(ms: list[Motion]) -> list[Motion]:
        # cycles are judged on the motions as denoised (rest-pose frames cut off)
        lps = loops if loops is not None else loops_of(ms, settings)
        if settings.optimize_steps:  # the networks adapt to all of the motions at once
            out = run(ms, lps, progress, on_fallback, on_blend)
            return smoothed(out, ms, lps, settings.smoothing(), settings.fill, on_smooth)
        feet = lock_config(settings)

        def lock(joined: Motion, source: Motion) -> Motion:
            return joined if feet is None else lock_motions([joined], [source], body, feet)[0]

        side = SIDE_BY_SIDE_REFINED if settings.refine_steps else SIDE_BY_SIDE_PIECES
        out = denoise_in_pieces(ms, lps, run, progress, on_fallback, on_blend, finish=lock,
                                side_by_side=side)  # fmt: skip
        return smoothed(out, ms, lps, settings.smoothing(), settings.fill, on_smooth)

    out = keep_rest_frames(motions, run_all) if settings.rest_pose else run_all(motions)
    return [unshared(o, m) for o, m in zip(out, motions, strict=True)]


def smoothing_share(level: float) -> float:
    """How much of the kind's smoothing a take gets from how noisy its input reads (``level``,
    rad: ``noise_blend.noise_level``): none up to half of ``fill.TAKE_NOISE_RAD`` (a clean
    take, or a video pipeline's output that it smoothed itself, comes back as the rest of the
    default leaves it), all of it from ``TAKE_NOISE_RAD`` on, linear between."""
    half = 0.5 * TAKE_NOISE_RAD
    return float(np.clip((level - half) / half, 0.0, 1.0))


def smoothed(
    results: list[Motion],
    sources: list[Motion],
    loops: list[bool],
    seconds: float,
    fill: str,
    on_smooth: Callable[[int, float], None] | None = None,
) -> list[Motion]:
    """Each result smoothed by a Gaussian of up to ``seconds`` (``KindSettings.smooth_s``; 0:
    as they are), scaled by how noisy its source reads (:func:`smoothing_share`): rotations as
    quaternions, the translation as it is (``filters``). A cycle stays as it is (a Gaussian
    with ends would open its seam); with the fill "off" the source's holes are written back
    as they came. ``on_smooth(index, seconds)``: the Gaussian each one got (0: none)."""
    out = []
    for i, (result, source, loop) in enumerate(zip(results, sources, loops, strict=True)):
        share = 0.0
        if seconds > 0 and not loop and result.num_frames >= 4:
            share = smoothing_share(noise_level(source))
        if on_smooth is not None:
            on_smooth(i, share * seconds)
        if share == 0.0:
            out.append(result)
            continue
        smooth = gaussian_filter_motion(result, share * seconds * result.fps)
        out.append(fill_holes(source, smooth, "off") if fill == "off" else smooth)
    return out


def lock_config(settings: DenoiseSettings) -> FootLockConfig | None:
    """The foot lock's settings for ``settings`` (None with ``feet="off"``): a kind whose feet
    may read clean and still jitter (video) has them smoothed as the lock's goal, and its
    contacts held to their means however far they stray (a video estimate's standing foot
    drifts by decimetres in depth: no sign of a foot that travels, ``travel_tol``)."""
    if settings.feet != "lock":
        return None
    if kind_settings(settings.input_kind).feet_as_came:
        return FootLockConfig()
    return FootLockConfig(clean_jitter=0.0, travel_tol=math.inf)
