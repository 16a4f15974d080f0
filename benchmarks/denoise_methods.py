"""The methods of the denoising table and the table's computation (``benchmarks/denoise_table.py``).

Filters tuned by grid search, regression / optimisation mode, the offset, refinement, the
mirror; every method run file to file on every noise level."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]
try:
    from benchmarks.denoise_rows import (
        FILTER_ROWS,
        ROW_GAUSSIAN,
        ROW_GT,
        ROW_OBS,
        ROW_OFFSET,
        ROW_OFFSET_FEET,
        ROW_OPTIMIZATION,
        ROW_OPTIMIZATION_OFFSET,
        ROW_REFINE,
        ROW_REFINE_MIRROR,
        ROW_REGRESSION,
        ROW_REGRESSION_MIRROR,
        ROW_SAVGOL,
        ROWS,
        CurvePoint,
        FilterTuning,
        Process,
        RowResult,
        TableResult,
        TableSettings,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_rows import (  # type: ignore[no-redef]
        FILTER_ROWS,
        ROW_GAUSSIAN,
        ROW_GT,
        ROW_OBS,
        ROW_OFFSET,
        ROW_OFFSET_FEET,
        ROW_OPTIMIZATION,
        ROW_OPTIMIZATION_OFFSET,
        ROW_REFINE,
        ROW_REFINE_MIRROR,
        ROW_REGRESSION,
        ROW_REGRESSION_MIRROR,
        ROW_SAVGOL,
        ROWS,
        CurvePoint,
        FilterTuning,
        Process,
        RowResult,
        TableResult,
        TableSettings,
    )

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_filter_motion, savgol_filter_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.metrics import EvalResult
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.motion.motion import Motion

# --------------------------------------------------------------------------------------------
# computing the table


def _no_log(message: str) -> None:
    pass


def tune_filters(
    val_clips: Sequence[common.Clip], body: BodyModel, settings: TableSettings, log=_no_log
) -> FilterTuning:
    """Grid-search the filters on noisy val clips (reference sigma) for the lowest V2V."""
    gt = [c.motion for c in val_clips]
    noisy = common.add_noise(val_clips, settings.reference_sigma, settings.seed)
    candidates: dict = {"obs": noisy}
    for s in settings.gaussian_grid:
        candidates[("gaussian", s)] = common.LazyMap(
            lambda m, s=s: gaussian_filter_motion(m, s), noisy
        )
    for w, p in settings.savgol_grid:
        candidates[("savgol", (w, p))] = common.LazyMap(
            lambda m, w=w, p=p: savgol_filter_motion(m, w, p), noisy
        )
    log(f"tuning filters: {len(candidates) - 1} settings on {len(val_clips)} val clips")
    scores = {k: r.v2v_cm for k, r in common.evaluate_clips(gt, candidates, body).items()}
    return FilterTuning(
        noise_sigma=settings.reference_sigma,
        clips=len(val_clips),
        gaussian_scores={k[1]: v for k, v in scores.items() if k[0] == "gaussian"},
        savgol_scores={k[1]: v for k, v in scores.items() if k[0] == "savgol"},
        observations_v2v=scores["obs"],
    )


def _per_clip(fn: Callable[[Motion], Motion]) -> Process:
    return lambda motions: [fn(m) for m in motions]


def _denoise(
    denoiser: Denoiser,
    body: BodyModel,
    s: TableSettings,
    steps: int,
    refine: int | None = None,
    mirror: bool = False,
    feet: bool = False,
) -> Process:
    """Regression (steps 0) or optimisation mode; ``refine``: None = no refinement, 0 = the
    closed-form offset alone, N = N refinement steps (with the offset); ``mirror``: average
    with the mirror image's result (``mdvae denoise --mirror``); ``feet``: then hold the feet
    still on the floor (``mdvae denoise --feet lock``). Run through the library call
    ``mdvae denoise`` makes (``infer.denoise_settings.denoise``), so with the offset (refine
    not None) the input's unexplained part is blended back as the command does; the paper's
    modes run untouched."""
    settings = DenoiseSettings(
        refine_steps=refine or 0,
        refine_lr=s.refine_lr,
        offset=refine is not None,
        offset_std=s.refine_offset,
        feet="lock" if feet else "off",
        mirror=mirror,
        optimize_steps=steps,
        lr=s.lr,
        seed=s.seed,
        window=s.window,
        overlap=s.window - s.stride,
    )

    def process(motions: list[Motion]) -> list[Motion]:
        # optimisation mode fine-tunes a copy of the networks (denoise() makes it)
        return denoise(motions, settings, denoiser, body)

    return process


def build_table(
    test_clips: Sequence[common.Clip],
    val_clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    settings: TableSettings,
    workdir: Path,
    log: Callable[[str], None] = _no_log,
    split: str = "test",
    tuned_on: str = "val",
) -> TableResult:
    """Run every method on every noise level and collect the table and the curve.

    test_clips, val_clips: clips at 30 Hz, all of the same length (the filters are tuned on
    ``val_clips``, which may be the test clips themselves: ``tuned_on`` says which); workdir:
    an empty folder for the noisy and denoised files (emptied again as it goes).
    """
    if not test_clips or not val_clips:
        raise ValueError("need at least one test clip and one val clip")
    if settings.reference_sigma not in settings.sigmas:
        raise ValueError(f"reference sigma {settings.reference_sigma:g} is not among the sigmas")
    s = settings
    tuning = tune_filters(val_clips, body, s, log)
    g_sigma, (sg_w, sg_p) = tuning.gaussian_sigma, tuning.savgol
    log(f"tuned: Gaussian sigma {g_sigma:g} frames; Savitzky-Golay window {sg_w}, order {sg_p}")
    methods: dict[str, tuple[str, Process]] = {
        ROW_GAUSSIAN: (
            f"σ = {g_sigma:g} frames",
            _per_clip(lambda m: gaussian_filter_motion(m, g_sigma)),
        ),
        ROW_SAVGOL: (
            f"window {sg_w}, order {sg_p}",
            _per_clip(lambda m: savgol_filter_motion(m, sg_w, sg_p)),
        ),
        ROW_REGRESSION: (
            "one forward pass (the paper's; `--no-offset`)",
            _denoise(denoiser, body, s, 0),
        ),
        ROW_REGRESSION_MIRROR: (
            "one forward pass on the clip and on its mirror image, averaged",
            _denoise(denoiser, body, s, 0, mirror=True),
        ),
        ROW_OFFSET: (
            f"one forward pass + closed-form slow offsets {s.refine_offset:g} rad, "
            f"{RefineConfig.trans_offset_std:g} m on the root, the input's unexplained part "
            "blended back (`mdvae denoise --feet off`)",
            _denoise(denoiser, body, s, 0, 0),
        ),
        ROW_OFFSET_FEET: (
            "the above, then feet held still on the floor where they are down (`mdvae denoise`)",
            _denoise(denoiser, body, s, 0, 0, feet=True),
        ),
        ROW_OPTIMIZATION: (
            f"{s.optimize_steps} steps on each sigma's set, lr {s.lr:g} (`--optimize`)",
            _denoise(denoiser, body, s, s.optimize_steps),
        ),
        ROW_OPTIMIZATION_OFFSET: (
            f"optimization mode, then the slow offset (`--optimize {s.optimize_steps}`)",
            _denoise(denoiser, body, s, s.optimize_steps, 0),
        ),
        ROW_REFINE: (
            f"regression + {s.refine_steps} steps per window, lr {s.refine_lr:g}, "
            f"slow offset {s.refine_offset:g} rad",
            _denoise(denoiser, body, s, 0, s.refine_steps),
        ),
        ROW_REFINE_MIRROR: (
            "latent refinement on the clip and on its mirror image, averaged",
            _denoise(denoiser, body, s, 0, s.refine_steps, mirror=True),
        ),
    }
    if s.rows is not None:
        methods = {k: v for k, v in methods.items() if k in s.rows or k in FILTER_ROWS}
    rows = {ROW_GT: RowResult(ROW_GT), ROW_OBS: RowResult(ROW_OBS)}
    rows.update({name: RowResult(name, params) for name, (params, _) in methods.items()})
    curve_steps = s.curve_steps if ROW_OPTIMIZATION in methods else ()
    extra_steps = [n for n in curve_steps if n not in (0, s.optimize_steps)]
    extra: dict[int, tuple[EvalResult, common.Timing]] = {}
    gt = [c.motion for c in test_clips]

    for sigma in s.sigmas:
        noisy = common.add_noise(test_clips, sigma, s.seed)
        folder = workdir / f"sigma_{sigma:g}"
        files = common.write_motions(noisy, folder / "noisy")
        predictions: dict = {ROW_OBS: noisy}
        timings: dict = {}
        runs: list[tuple[object, Process]] = [(n, p) for n, (_, p) in methods.items()]
        if sigma == s.reference_sigma:
            runs += [(n, _denoise(denoiser, body, s, n)) for n in extra_steps]
        for key, process in runs:
            log(f"sigma {sigma:g}: {key if isinstance(key, str) else f'{key} steps'}")
            outs, timings[key] = common.file_to_file(files, folder / "out", process)
            predictions[key] = [common.compact(o, g) for o, g in zip(outs, gt, strict=True)]
            shutil.rmtree(folder / "out")
        if sigma == s.reference_sigma:
            for name in (
                ROW_GAUSSIAN,
                ROW_SAVGOL,
                ROW_REGRESSION,
                ROW_REGRESSION_MIRROR,
                ROW_OFFSET,
                ROW_OFFSET_FEET,
            ):
                if name not in methods:
                    continue
                out = folder / "one"
                rows[name].one_clip_s = common.warm_median_seconds(
                    lambda p=methods[name][1], out=out, one=files[:1]: common.file_to_file(
                        one, out, p
                    ),
                    s.single_clip_repeats,
                )
        log(f"sigma {sigma:g}: evaluating {len(predictions)} sets of {len(gt)} clips")
        evaluated = common.evaluate_clips(gt, predictions, body)
        obs = evaluated[ROW_OBS]
        rows[ROW_GT].results[sigma] = replace(
            obs, v2v_cm=0.0, v2v_abs_cm=0.0, mpjpe_cm=0.0, accel_pred=obs.accel_gt, accel_error=0.0,
            foot_skate_pred=obs.foot_skate_gt, foot_slide_pred=obs.foot_slide_gt,
            penetration_pred=obs.penetration_gt, float_pred=obs.float_gt,
        )  # fmt: skip
        for key, result in evaluated.items():
            if isinstance(key, int):
                extra[key] = (result, timings[key])
            else:
                rows[key].results[sigma] = result
                if sigma == s.reference_sigma and key in timings:
                    rows[key].speed = timings[key]
        shutil.rmtree(folder)

    ref = s.reference_sigma
    curve = []
    for n in curve_steps:
        if n in extra:
            result, timing = extra[n]
        else:
            row = rows[ROW_REGRESSION if n == 0 else ROW_OPTIMIZATION]
            result, timing = row.results[ref], row.speed
        curve.append(CurvePoint(f"{n} steps", n, timing.s_per_frame, result.v2v_cm))
    for name in (
        *FILTER_ROWS,
        ROW_OFFSET,
        ROW_OPTIMIZATION_OFFSET,
        ROW_REFINE,
        ROW_REGRESSION_MIRROR,
        ROW_REFINE_MIRROR,
    ):
        if name in rows:
            r = rows[name]
            curve.append(CurvePoint(name, None, r.speed.s_per_frame, r.v2v(ref)))
    return TableResult(
        settings=s,
        rows=[rows[n] for n in ROWS if n in rows],
        tuning=tuning,
        curve=curve,
        num_clips=len(test_clips),
        clip_frames=test_clips[0].motion.num_frames,
        split=split,
        tuned_on=tuned_on,
    )
