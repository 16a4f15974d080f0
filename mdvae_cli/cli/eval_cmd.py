"""``mdvae eval``: compare predictions with ground truth (V2V, MPJPE, accelerations, feet)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.batch import FileJob, FileOutcome, emit_json, json_option, print_notes, run_batch
from mdvae_cli.cli.common import (
    POSITIVE,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.eval_pairs import NoPartner, base_name, pair_files
from mdvae_cli.cli.motion_input import input_fps_option, one_track, track_option
from mdvae_cli.cli.takes import take_options, take_reading
from mdvae_cli.errors import InputError
from mdvae_cli.foot_metrics import SLIDE_SPEED
from mdvae_cli.formats.registry import ReadOptions, read
from mdvae_cli.motion.contacts import FLOOR_QUANTILE, HEIGHT_TOL, SPEED_MAX

if TYPE_CHECKING:  # the metrics pose meshes with torch: imported when the command runs
    from mdvae_cli.metrics import EvalResult

#: units of the EvalResult fields, also written into the JSON output
UNITS = {
    "v2v_cm": "cm",
    "v2v_abs_cm": "cm",
    "mpjpe_cm": "cm",
    "mpjpe_root_cm": "cm",
    "accel_gt": "m/s^2",
    "accel_pred": "m/s^2",
    "accel_error": "m/s^2",
    "foot_skate_gt": "cm/s",
    "foot_skate_pred": "cm/s",
    "foot_slide_gt": "%",
    "foot_slide_pred": "%",
    "penetration_gt": "cm",
    "penetration_pred": "cm",
    "float_gt": "cm",
    "float_pred": "cm",
    "floor_m": "m",
}


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _pair(pred: float | None, gt: float | None) -> str:
    return f"{_fmt(pred)} ({_fmt(gt)})"


#: the table's metric names, in the order of :func:`_cells`
METRIC_NAMES = ("frames", "V2V", "V2V abs", "MPJPE root", "MPJPE world", "acc GT", "acc pred",
                "acc err", "skate", "slide %", "penetr.", "float")  # fmt: skip
_CAPTION = "errors in cm, accelerations in m/s², skate in cm/s; feet: pred (GT)"
#: the widest console the one-row-per-file table is printed on; narrower: one column per file
WIDE_TABLE = 150


def results_table(
    rows: list[tuple[str, EvalResult]], mean: EvalResult | None, width: int = 200
) -> list[Table]:
    """Rich tables of the results: one row per file then the frame-weighted mean when
    ``width`` (the console's columns) holds it; else one row per metric, a column per file,
    as many files per table as fit."""
    if width >= WIDE_TABLE:
        return [_wide_table(rows, mean)]
    named = [*rows, *([("mean (frame-weighted)", mean)] if mean is not None else [])]
    per = max(1, (width - 14) // 16)
    tables = []
    for start in range(0, len(named), per):
        table = Table(title="Evaluation" if not start else None, title_justify="left",
                      caption=_CAPTION if start + per >= len(named) else None,
                      caption_justify="left")  # fmt: skip
        table.add_column("metric", no_wrap=True)
        chunk = named[start : start + per]
        for name, _ in chunk:
            table.add_column(escape(name), justify="right", overflow="fold", max_width=16)
        columns = [_cells(r) for _, r in chunk]
        for i, metric in enumerate(METRIC_NAMES):
            table.add_row(metric, *(c[i] for c in columns))
        tables.append(table)
    return tables


def _wide_table(rows: list[tuple[str, EvalResult]], mean: EvalResult | None) -> Table:
    table = Table(title="Evaluation", title_justify="left", caption=_CAPTION,
                  caption_justify="left")  # fmt: skip
    table.add_column("file", overflow="fold", min_width=12)
    for name in METRIC_NAMES:
        table.add_column(name, justify="right", no_wrap=True)
    for name, r in rows:
        table.add_row(escape(name), *_cells(r))
    if mean is not None:
        table.add_section()
        table.add_row("[bold]mean (frame-weighted)[/]", *_cells(mean))
    return table


def _cells(r: EvalResult) -> list[str]:
    return [
        str(r.num_frames),
        _fmt(r.v2v_cm),
        _fmt(r.v2v_abs_cm),
        _fmt(r.mpjpe_root_cm),
        _fmt(r.mpjpe_cm),
        _fmt(r.accel_gt),
        _fmt(r.accel_pred),
        _fmt(r.accel_error),
        _pair(r.foot_skate_pred, r.foot_skate_gt),
        _pair(r.foot_slide_pred, r.foot_slide_gt),
        _pair(r.penetration_pred, r.penetration_gt),
        _pair(r.float_pred, r.float_gt),
    ]


_SLIDE_CM = 100 * SLIDE_SPEED / 30  # a sliding foot's travel in one frame at 30 Hz
#: ``mdvae eval --help``; the contact rule's numbers are the ones ``motion.contacts`` uses
HELP = f"""Score predicted motions against ground truth.

\b
Per file, both motions posed by the body model with the ground truth's betas:
  V2V       vertex error, root-relative (each mesh minus its pelvis), cm
  V2V abs   vertex error in world coordinates, cm
  MPJPE     error of the 22 body joints, cm: root-relative (each skeleton
            minus its pelvis, as in the literature) and in world coordinates
  acc       mean joint |x[t-1] - 2x[t] + x[t+1]| * fps^2, m/s^2 (GT, pred)
  acc err   mean norm of the difference of accelerations, m/s^2
Feet, where the ground truth has a foot down by the rule mdvae view marks
contacts with (its ankle or ball joint less than {100 * HEIGHT_TOL:g} cm above its own
floor level, the {100 * FLOOR_QUANTILE:g} % quantile of its height over the take, and
slower than {SPEED_MAX:g} m/s), against the ground truth's floor (the median height
of its lowest sole points there); prediction (GT):
  skate     mean horizontal speed of contacting foot joints, cm/s
  slide %   share of them faster than {SLIDE_SPEED:g} m/s ({_SLIDE_CM:g} cm per frame at 30 Hz)
  penetr.   mean depth of each foot's lowest point under the floor, cm
  float     its mean height above the floor while the foot is down, cm
The mean row weights every frame equally (skate: every contact pair; float:
every foot-frame down). Frames missing in either file (holes: NaN rows, a
video track's skipped frames, filled or not) are not scored; a note says
how many, and `frames` counts those scored. Files at different frame rates are scored at the
slower rate (the faster one resampled, with a note); lengths must match there, but for
a last frame past the other file's end, which the note says is not scored (31 frames at
24 fps against their 38 at 30 fps: 30 scored). --fps gives the rate of both
sides, --gt-fps or --pred-fps that of one (a 120 Hz BVH whose Frame Time is wrong
against a video pipeline's output, which stores no rate: --gt-fps 120 --pred-fps 30).

Two folders are paired by relative path, then by name in the same sub-folder where one file
fits (walk.bvh with walk.npz or walk_clean.npz): a note says each pair made by name and each
prediction left without ground truth; a file several predictions fit fails alone.

With --json the columns are keys of each file's "result": V2V v2v_cm (root-relative) and
v2v_abs_cm (world), MPJPE mpjpe_root_cm (root-relative) and mpjpe_cm (world), accel_gt,
accel_pred, accel_error, then foot_skate_, foot_slide_, penetration_ and float_ with _pred
and _gt.

\b
Example:
  mdvae eval --gt clean/ --pred denoised/ --json > scores.json
"""  # fmt: skip


@click.command("eval", help=HELP)
@click.option(
    "--gt", "gt", type=click.Path(path_type=Path), required=True,
    help="Ground-truth motion file or folder: any file `mdvae denoise` reads (.npz, .bvh, "
    ".amc, video pipelines' outputs).",
)  # fmt: skip
@click.option(
    "--pred", "pred", type=click.Path(path_type=Path), required=True,
    help="Predicted motion file or folder (folders are matched to --gt by relative path, "
    "then by name where one file fits: walk_clean.npz or walk.npz for walk.bvh).",
)  # fmt: skip
@body_model_option
@click.option(
    "--chunk-frames", type=click.IntRange(min=1), default=256, show_default=True,
    help="Frames posed at once (bounds memory on long files).",
)  # fmt: skip
@take_options
@input_fps_option
@click.option(
    "--gt-fps", type=POSITIVE, default=None,
    help="Frame rate of the ground truth alone (overrides --fps for it): a 120 Hz capture "
    "scored against a 30 Hz prediction, say.",
)  # fmt: skip
@click.option(
    "--pred-fps", type=POSITIVE, default=None,
    help="Frame rate of the predictions alone (overrides --fps for them): a video "
    "pipeline's output, which stores none, scored against a file that holds its own.",
)  # fmt: skip
@track_option("score this track (its id in the file) of both")
@allow_pickle_option
@json_option
@handle_errors
def eval_command(
    gt, pred, body_model, chunk_frames, asf, joint_map_file, input_fps, gt_fps, pred_fps, track,
    allow_pickle, as_json,
) -> None:  # fmt: skip
    from mdvae_cli.export import as_body_model
    from mdvae_cli.metrics import common_rate, evaluate_pair, mean_result

    jobs, unmatched, paired = pair_files(gt, pred)
    body = as_body_model(load_body_model(body_model))
    options = ReadOptions(allow_pickle=allow_pickle, body=body.data,
                          **take_reading(asf, joint_map_file))  # fmt: skip
    gt_options, pred_options = side_options(options, input_fps, gt_fps, pred_fps)
    for line in paired:
        console.print(f"[dim]note: {escape(line)}[/]", soft_wrap=True)
    for path in unmatched:
        console.print(f"[dim]note: {escape(str(path))} has no ground truth; skipped[/]",
                      soft_wrap=True)  # fmt: skip

    def process(job: FileJob) -> EvalResult:
        if isinstance(job.data, NoPartner):
            raise InputError(f"{job.source}: no prediction paired: {job.data.reason}")
        if not Path(job.data).exists():
            stem = base_name(job.relpath)
            raise InputError(f"{job.source}: no prediction: no {job.data}, nor one named "
                             f"{stem}.* or {stem}_*.* beside it")  # fmt: skip
        truth = one_track(read(job.source, gt_options), track)
        guess = one_track(read(job.data, pred_options), track)
        try:
            truth, guess, note = common_rate(truth, guess)
            result = evaluate_pair(truth, guess, body, chunk_frames=chunk_frames)
            if result.unscored_frames:
                note = (f"{note}; " if note else "") + (
                    f"{result.unscored_frames} of {result.unscored_frames + result.num_frames} "
                    "frames missing (holes) in the ground truth or the prediction: not scored"
                )
            print_notes(job.relpath, [note] if note else [])
            return result
        except InputError as exc:
            raise InputError(f"{job.source} vs {job.data}: {exc}") from None

    report = run_batch(jobs, process, "eval", quiet=as_json)
    good: list[FileOutcome] = report.succeeded
    mean = mean_result([o.result for o in good]) if good else None
    if as_json:
        emit_json(
            {
                "files": [
                    {
                        "file": o.job.relpath.as_posix(),
                        "gt": str(o.job.source),
                        "pred": None if isinstance(o.job.data, NoPartner) else str(o.job.data),
                        "ok": o.ok,
                        "error": o.error,
                        "result": o.result.to_dict() if o.ok else None,
                    }
                    for o in report.outcomes
                ],
                "mean": None if mean is None else mean.to_dict(),
                "failed": len(report.failed),
                "unpaired_predictions": [str(p) for p in unmatched],
                "units": UNITS,
                "body_model": body.data.name or body.data.kind,
            }
        )
    elif good:
        rows = [(o.job.relpath.as_posix(), o.result) for o in good]
        out = table_console()
        for table in results_table(rows, mean if len(good) > 1 else None, out.width):
            out.print(table)
    report.exit()


def side_options(
    options: ReadOptions, both: float | None, gt_fps: float | None, pred_fps: float | None
) -> tuple[ReadOptions, ReadOptions]:
    """How the ground truth and the predictions are read: ``options`` with each side's frame
    rate, its own (``--gt-fps`` / ``--pred-fps``) where given, else ``--fps`` (both)."""
    return (
        replace(options, fps=both if gt_fps is None else gt_fps),
        replace(options, fps=both if pred_fps is None else pred_fps),
    )


def table_console() -> Console:
    """Where the results table goes: the console on a terminal; off one (logs, pipes), as many
    columns as ``COLUMNS`` says, else 200 (rich would cut the table at 80)."""
    if console.is_terminal:
        return console
    columns = os.environ.get("COLUMNS", "")
    return Console(stderr=True, width=int(columns) if columns.isdigit() else 200)


COMMANDS = [eval_command]
