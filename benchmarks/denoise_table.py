"""Motion-DVAE paper Table 1 and Figure 1 on held-out CMU subjects.

    python benchmarks/denoise_table.py [--corpus data/cmu_amass] [--out docs/benchmarks.md]
                                       [--max-clips N] [--quick]

Protocol. The test-split files (resampled to 30 Hz) are cut into non-overlapping 60-frame
(2 s) clips. Pose-NDF noise of sigma = 0.10, 0.15 and 0.20 rad is added to every clip, with a
seed fixed per clip and sigma. Every method then runs file to file on the noisy clips, and the
timed part is loading, denoising and saving all of them in one run:

* ground truth and observations (the noisy input), for reference;
* a Gaussian and a Savitzky-Golay filter (``mdvae_cli.filters``). Their parameters are tuned by
  grid search on clips of the val split at sigma = 0.15, for the lowest V2V;
* regression mode: one forward pass of the denoiser;
* optimisation mode: for each sigma, a copy of the denoiser is fine-tuned for 50 steps on all
  the test clips of that sigma at once, which then predicts them (the paper's protocol);
* refinement (``mdvae denoise --refine 50``): regression mode, then 50 gradient steps on each
  window's own latents, with a slow rotation offset (``mdvae_cli.infer.refine``).

The metrics are root-relative V2V (cm) and the mean joint acceleration (m/s^2; the ground truth
row gives the target value), frame-weighted over all clips. Speed is s/frame and frames/s of the
file-to-file run at sigma = 0.15, plus, for the filters and regression mode, one clip processed
alone after a warm-up. Figure 1 plots V2V against s/frame at sigma = 0.15 for 0, 20, 50, 100
and 250 optimisation steps, with the filters as reference points (matplotlib, optional).

The table, the machine description and the plot link go into a marked section of ``--out``
(other content of that file is kept). ``--quick`` runs a small subset to check that everything
works. Its numbers mean little, and it writes ``--out`` only when that is given explicitly.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/denoise_table.py
    import common  # type: ignore[no-redef]
try:
    from benchmarks.denoise_rows import (
        CURVE_STEPS,
        FILTER_ROWS,
        REPO,
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
        SECTION_BEGIN,
        SECTION_END,
        CurvePoint,
        FilterTuning,
        Process,
        RowResult,
        TableResult,
        TableSettings,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_rows import (  # type: ignore[no-redef]
        CURVE_STEPS,
        FILTER_ROWS,
        REPO,
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
        SECTION_BEGIN,
        SECTION_END,
        CurvePoint,
        FilterTuning,
        Process,
        RowResult,
        TableResult,
        TableSettings,
    )
try:
    from benchmarks.denoise_report import (
        plot_speed_accuracy,
        report_markdown,
        table_columns,
        table_rows,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_report import (  # type: ignore[no-redef]
        plot_speed_accuracy,
        report_markdown,
        table_columns,
        table_rows,
    )

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_filter_motion, savgol_filter_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig
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
    with the mirror image's result (``mdvae denoise --mirror``); ``feet``: then lock the feet
    (``mdvae denoise --feet lock``)."""
    cfg = None
    if refine is not None:
        cfg = RefineConfig(steps=refine, lr=s.refine_lr, offset_std=s.refine_offset)

    def process(motions: list[Motion]) -> list[Motion]:
        # optimisation mode fine-tunes the networks it is given: always a fresh copy
        model = copy.deepcopy(denoiser) if steps else denoiser
        return denoise_motions(
            motions, model, body, s.window, s.stride, steps, s.lr, s.batch_size, s.seed,
            refine=cfg, mirror=mirror, feet=FootLockConfig() if feet else None,
        )  # fmt: skip

    return process


def build_table(
    test_clips: Sequence[common.Clip],
    val_clips: Sequence[common.Clip],
    denoiser: Denoiser,
    body: BodyModel,
    settings: TableSettings,
    workdir: Path,
    log: Callable[[str], None] = _no_log,
) -> TableResult:
    """Run every method on every noise level and collect the table and the curve.

    test_clips, val_clips: clips at 30 Hz, all of the same length; workdir: an empty folder for
    the noisy and denoised files (emptied again as it goes).
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
            f"{RefineConfig.trans_offset_std:g} m on the root (`mdvae denoise`)",
            _denoise(denoiser, body, s, 0, 0),
        ),
        ROW_OFFSET_FEET: (
            "the above, then feet held still on the floor where they are down (`--feet lock`)",
            _denoise(denoiser, body, s, 0, 0, feet=True),
        ),
        ROW_OPTIMIZATION: (
            f"{s.optimize_steps} steps on each sigma's set, lr {s.lr:g}, batch {s.batch_size}",
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
    rows = {ROW_GT: RowResult(ROW_GT), ROW_OBS: RowResult(ROW_OBS)}
    rows.update({name: RowResult(name, params) for name, (params, _) in methods.items()})
    extra_steps = [n for n in s.curve_steps if n not in (0, s.optimize_steps)]
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
    for n in s.curve_steps:
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
        r = rows[name]
        curve.append(CurvePoint(name, None, r.speed.s_per_frame, r.v2v(ref)))
    return TableResult(
        settings=s,
        rows=[rows[n] for n in ROWS],
        tuning=tuning,
        curve=curve,
        num_clips=len(test_clips),
        clip_frames=test_clips[0].motion.num_frames,
    )


# --------------------------------------------------------------------------------------------
# command line


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "cmu_amass")
    p.add_argument("--split", type=Path, help="split file (default: CORPUS/split.json)")
    p.add_argument(
        "--out",
        type=Path,
        help="markdown file to write the section into (default: docs/benchmarks.md; "
        "with --quick only when given)",
    )
    p.add_argument("--plot", type=Path, help="PNG (default: denoise_speed_accuracy.png by --out)")
    p.add_argument("--json", type=Path, help="also write the raw numbers here")
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--body-model", type=Path, help="SMPL-family file (default: built-in body)")
    p.add_argument("--max-files", type=int, help="use at most this many files per split")
    p.add_argument("--max-clips", type=int, help="test clips to use, spread evenly (default all)")
    p.add_argument("--tune-clips", type=int, default=100, help="val clips for the filter grid")
    p.add_argument("--clip-frames", type=int, default=60, help="frames per clip (2 s at 30 Hz)")
    p.add_argument("--optimize-steps", type=int, default=50)
    p.add_argument("--curve-steps", default=",".join(map(str, CURVE_STEPS)))
    p.add_argument(
        "--refine-steps", type=int, default=RefineConfig.steps, help="steps of the refinement row"
    )
    p.add_argument(
        "--refine-offset",
        type=float,
        default=RefineConfig.offset_std,
        help="slow-offset scale of the refinement row",
    )
    p.add_argument("--threads", type=int, default=2, help="torch threads (the product's target)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workdir", type=Path, help="scratch folder (default: a temporary one)")
    p.add_argument("--quick", action="store_true", help="a small subset, to check the script")
    return p.parse_args(argv)


def settings_from_args(args: argparse.Namespace, window: int) -> TableSettings:
    s = TableSettings(
        optimize_steps=args.optimize_steps,
        curve_steps=tuple(int(x) for x in str(args.curve_steps).split(",") if x.strip()),
        window=window,
        stride=max(1, window * 3 // 4),
        seed=args.seed,
        refine_steps=args.refine_steps,
        refine_offset=args.refine_offset,
    )
    if args.quick:
        s.refine_steps = min(s.refine_steps, 10)
        s.gaussian_grid = (1.0, 2.0, 3.0)
        s.savgol_grid = ((7, 2), (11, 2), (15, 3))
        s.curve_steps = tuple(n for n in s.curve_steps if n <= s.optimize_steps)
        s.single_clip_repeats = 2
    return s


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with an ``error:`` line when the inputs are missing."""
    command = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(command)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        return _run(args, command)
    finally:
        torch.set_num_threads(previous_threads)  # leave a calling process as it was


def _run(args: argparse.Namespace, command: list[str]) -> int:
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.errors import MdvaeError
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.train.corpus import read_split

    if args.quick:
        args.max_files = args.max_files or 6
        args.max_clips = args.max_clips or 24
        args.tune_clips = min(args.tune_clips, 12)
    start = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - start:7.1f}s] {message}", file=sys.stderr, flush=True)

    try:
        split_file = args.split or args.corpus / "split.json"
        if not split_file.is_file():
            raise MdvaeError(f"no split file at {split_file} (is the corpus built?)")
        split = read_split(split_file)
        missing = [k for k in ("test", "val") if not split.get(k)]
        if missing:
            raise MdvaeError(f"{split_file}: no files in split(s) {', '.join(missing)}")
        denoiser, meta = load_denoiser(args.denoiser)
        window = int(meta.get("fit_config", {}).get("window", 60))
        body = BodyModel(load_body_model(args.body_model))
        root = split_file.parent
        test_files = common.pick_evenly(split["test"], args.max_files)
        val_files = common.pick_evenly(split["val"], args.max_files)
        log(f"loading {len(test_files)} test and {len(val_files)} val files")
        test = common.load_clips(test_files, root, args.clip_frames, max_clips=args.max_clips)
        val = common.load_clips(val_files, root, args.clip_frames, max_clips=args.tune_clips)
        if not test or not val:
            raise MdvaeError(f"no clip of {args.clip_frames} frames in the test or val files")
        settings = settings_from_args(args, window)
        with tempfile.TemporaryDirectory(prefix="mdvae-bench-") as tmp:
            work = args.workdir or Path(tmp)
            work.mkdir(parents=True, exist_ok=True)
            result = build_table(test, val, denoiser, body, settings, work, log)
    except MdvaeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    out = args.out if (args.out or args.quick) else REPO / "docs" / "benchmarks.md"
    context = {
        "corpus": f"{args.corpus} (split {split_file.name}: {len(test_files)} test files, "
        f"{len(val_files)} val files used)",
        "denoiser": str(args.denoiser or "shipped weights (mdvae_cli/weights/denoiser.npz)"),
        "body model": str(args.body_model or "built-in body"),
        "denoiser windows": f"{settings.window} frames, stride {settings.stride}",
        "run": "quick subset (--quick): numbers are only a smoke test"
        if args.quick
        else ("all test clips" if args.max_clips is None and args.max_files is None else "subset"),
        "command": " ".join(["python benchmarks/denoise_table.py", *command]),
        "benchmark time": f"{time.perf_counter() - start:.0f} s",
    }
    machine = common.machine_description()
    plot_link = None
    if out is not None:
        plot = args.plot or out.parent / "denoise_speed_accuracy.png"
        if plot_speed_accuracy(result, plot):
            plot_link = os.path.relpath(plot, out.parent)
        else:
            log("matplotlib is not installed: no plot (pip install matplotlib)")
        common.write_section(
            out, report_markdown(result, machine, context, plot_link), SECTION_BEGIN, SECTION_END
        )
        log(f"wrote {out}" + (f" and {plot}" if plot_link else ""))
    if args.json:
        payload = {**result.to_dict(), "machine": machine, "context": context}
        args.json.write_text(json.dumps(payload, indent=2) + "\n")
    print(common.markdown_table(table_columns(settings), table_rows(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
