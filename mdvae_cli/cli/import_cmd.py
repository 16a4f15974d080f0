"""``mdvae import``: mocap files (BVH, ASF/AMC) -> AMASS-style .npz on the SMPL skeleton."""

from __future__ import annotations

import json
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    is_kind,
    json_option,
    plan_jobs,
    print_notes,
    run_batch,
    strip_gz,
)
from mdvae_cli.cli.common import (
    NON_NEGATIVE,
    POSITIVE,
    OutputPath,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.motion_input import FORMATS_HELP, format_choice, missing_option
from mdvae_cli.cli.takes import load_joint_map
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_named_file, write_atomic
from mdvae_cli.formats.registry import READ_SUFFIXES
from mdvae_cli.motion import cmu, corpus_plan, hdm05
from mdvae_cli.motion.motion import check_fps

#: what folders are searched for: every format ``formats.registry`` reads (mocap to retarget,
#: video pipelines' outputs, .npz ones such as SLAHMR's and ROMP's among them, and AMASS .npz,
#: written again in the import's layout), as for files given by name
SUFFIXES = READ_SUFFIXES


def plan_corpora(folders: list[Path], spec: corpus_plan.SplitSpec) -> list:
    """The import plan of every corpus folder (CMU or HDM05), each mirrored under its own name
    when there are several. InputError for a folder of neither kind."""
    items = []
    for folder in folders:
        if cmu.is_cmu_corpus(folder):
            planned = cmu.plan_corpus(folder, spec)
        elif hdm05.is_hdm05_corpus(folder):
            planned = hdm05.plan_hdm05(folder, spec)
        else:
            raise InputError(f"{folder}: not a CMU or HDM05 corpus folder")
        if len(folders) > 1:
            for item in planned:
                item.relpath = Path(folder.resolve().name) / item.relpath
        items += planned
    return items


def _output_name(relpath: Path) -> Path:
    return strip_gz(relpath).with_suffix(".npz")


_WORKER = None  # each --jobs process's FileImporter


def _start_worker(*args) -> None:
    """A worker process's setup. Ctrl-C is the parent's to handle: a worker interrupted while
    holding the pool's queue lock could leave the parent waiting forever; instead the parent
    cancels what has not started and the workers finish the file they are on (written
    atomically) and exit."""
    import signal

    from mdvae_cli.run.import_files import FileImporter

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    global _WORKER
    _WORKER = FileImporter(*args)


def _work(job: FileJob) -> dict:
    return _WORKER(job)


def _write_json(path: Path, data: dict) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2) + "\n"))


def _print_summary(summary: dict) -> None:
    table = Table(title="import summary", title_justify="left")
    for col in ("format", "files", "frames", "mean joint error"):
        table.add_column(col, justify="left" if col == "format" else "right")
    for fmt, row in summary["by_format"].items():
        table.add_row(fmt, str(row["files"]), str(row["frames"]), f"{row['retarget_error_mm']} mm")
    if summary["by_format"]:
        table.add_row("all", str(summary["succeeded"]), str(summary["frames"]),
                      f"{summary['retarget_error_mm']} mm", style="bold")  # fmt: skip
        console.print(table)
    for name, s in summary.get("splits", {}).items():
        if s["files"]:
            console.print(f"{name}: {s['files']} files, {s['frames']} frames ({s['minutes']} "
                          f"min), subjects {' '.join(s['subjects'])}")  # fmt: skip
    walk = summary.get("walking")
    if walk and walk["files"]:
        speed = walk["speed_mps"]
        console.print(f"walking trials: {walk['files']}, mean lowest-sole height "
                      f"{walk['sole_height_mean_cm']} cm, speed {speed['min']}-{speed['max']} "
                      f"m/s (mean {speed['mean']})")  # fmt: skip
    if summary["skipped"]:
        console.print(f"skipped: {len(summary['skipped'])} (duplicates, held-out donor files)")
    console.print(f"{summary['succeeded']} of {summary['succeeded'] + summary['failed']} files "
                  f"imported in {summary['elapsed_s']} s")  # fmt: skip


@click.command("import")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=OutputPath(), required=True,
    help="Output folder (inputs mirrored below it), or an .npz for a single input file.",
)  # fmt: skip
@click.option(
    "--fps", type=NON_NEGATIVE, default=None,
    help="Frame rate of the output; 0 keeps the source's. [default: 30 for mocap takes; a "
    "video pipeline's file keeps its own frames, as mdvae denoise reads it]",
)  # fmt: skip
@click.option(
    "--asf", type=click.Path(path_type=Path, dir_okay=False),
    help="Skeleton for .amc inputs (default: <subject>.asf or the only .asf next to each). "
    "An .asf among INPUTS does the same.",
)  # fmt: skip
@click.option(
    "--source-fps", type=POSITIVE,
    help="The inputs' true frame rate, when their files are wrong (AMC files assume 120).",
)  # fmt: skip
@click.option(
    "--scale", type=POSITIVE, metavar="METRES",
    help="Metres per file unit (default: ASF units; BVH guessed from the skeleton's height).",
)  # fmt: skip
@click.option(
    "--floor", type=click.Choice(["plane", "flat", "none"]), default=None,
    help="Put the ground under the soles at z=0, levelling a slightly tilted capture floor "
    "(plane), only shift heights (flat), or keep the source's heights (none). [default: plane "
    "for mocap takes; a video pipeline's file keeps the heights the pipeline wrote, as mdvae "
    "denoise reads it]",
)  # fmt: skip
@click.option(
    "--corpus", "--cmu-corpus", "corpus", is_flag=True,
    help="INPUTS are mocap corpus folders: CMU (asfamc/, bvh/, bvh_daz/, asfamc_noasf/: its "
    "60 Hz subjects, donor skeleton and duplicates are applied) and/or HDM05 (<actor>/ folders; "
    "held-out test data only). Writes split.json and summary.json; with several folders each "
    "is mirrored under its own name.",
)  # fmt: skip
@click.option(
    "--split", "split_file", type=click.Path(path_type=Path, dir_okay=False),
    help="With --corpus: JSON {val_subjects, test_subjects, unseen_val_subjects, "
    "unseen_test_subjects} (CMU numbers such as \"07\", HDM05 actors as \"hdm05:bd\"; default: "
    "val 06 35, test 02 07 09).",
)  # fmt: skip
@click.option(
    "--format", "input_format", type=format_choice(), default=None,
    help="Format of estimate files, when the file does not tell: " + FORMATS_HELP,
)  # fmt: skip
@click.option(
    "--track", default=None, metavar="ID",
    help="Files of several people: keep only this track (default: every track, each written "
    "to <output>.track<ID>.npz).",
)  # fmt: skip
@click.option(
    "-j", "--jobs", "jobs_n", type=click.IntRange(min=1), default=1, show_default=True,
    help="Worker processes (one CPU core each).",
)  # fmt: skip
@click.option(
    "--joint-map", "joint_map_file", type=click.Path(path_type=Path, dir_okay=False),
    help="For BVH/AMC takes whose joint names are not recognised: a JSON file naming them "
    '(SMPL joint -> yours, e.g. {"left_hip": "LeftUpLeg"}).',
)  # fmt: skip
@missing_option
@body_model_option
@json_option
@handle_errors
def import_command(inputs, out, fps, asf, source_fps, scale, floor, corpus, split_file,
                   input_format, track, jobs_n, joint_map_file, missing, body_model,
                   as_json) -> None:  # fmt: skip
    """Import motion capture (BVH, ASF/AMC; .gz too) as AMASS-style .npz on the SMPL skeleton,
    and the output files of video pose pipelines (WHAM, GVHMR, TRAM, 4D-Humans/PHALP, VIBE,
    PARE, HybrIK, ROMP/BEV, SLAHMR) or AIST++ pickles as AMASS-style .npz.

    Each mocap motion is retargeted onto the body model (the built-in body by default): its
    shape is fitted once per skeleton to the source's bone lengths, then the root and the 21
    body joints are solved per frame to match the source's joint positions. Output: z-up,
    floor at z=0, gender "neutral", resampled to --fps, with a 'source' record (JSON) of where
    it came from. The mean joint position error of the retarget is printed per file. A video
    pipeline's SMPL-family estimates need no retarget: they are made upright (z up), one output
    per person track (docs/formats.md), with the frames and heights the pipeline wrote (the
    same motion mdvae denoise reads from the file itself; --fps resamples them, --floor plane
    puts them on the floor); --source-fps gives their frame rate (they store none: 30 is
    assumed). A folder is searched for every file of these kinds (SLAHMR's and ROMP's .npz
    among them; an AMASS .npz is written again in this layout).

    \b
    Examples:
      mdvae import walk.bvh -o walk.npz
      mdvae import 07.asf 07_01.amc.gz 07_02.amc.gz -o out/
      mdvae import ../shared/data/cmu ../shared/data/hdm05 -o data/corpus --corpus \\
          --split weights_recipe/cmu_split.json --jobs 2
      mdvae import wham_output.pkl -o take.npz --source-fps 25
    """
    started = time.perf_counter()
    out_arg, out = out, Path(out)  # as typed: a trailing slash makes it a folder (plan_jobs)
    out_fps = 30.0 if fps is None else (fps if fps > 0 else None)  # mocap takes
    estimate_fps = None if fps is None else out_fps  # video estimates: their own by default
    for option, rate in (("--fps", out_fps), ("--source-fps", source_fps)):
        if rate is not None:
            check_fps(rate, option)
    inputs, asf = _skeleton_inputs(inputs, asf)
    jobs, skipped, spec = _plan(inputs, out, out_arg, asf, source_fps, corpus, split_file)

    from mdvae_cli.retarget.retarget import RetargetSettings

    settings = RetargetSettings(floor=floor or "plane").validate()
    joint_map = load_joint_map(joint_map_file)
    args = (body_model, out, out_fps, settings, source_fps, scale, asf, input_format, track,
            joint_map, estimate_fps, floor, missing, print_notes)  # fmt: skip
    report = _run(jobs, args, jobs_n)
    rows = [o.result for o in report.succeeded]
    summary = {**report.to_dict(), "skipped": skipped, "fps": out_fps,
               **corpus_plan.error_summary(rows)}  # fmt: skip
    if corpus:
        summary["splits"] = corpus_plan.split_summary(rows, out_fps)
        summary["walking"] = cmu.walking_summary(rows)
        summary["acknowledgement"] = cmu.ACKNOWLEDGEMENT
    summary["elapsed_s"] = round(time.perf_counter() - started, 1)
    if corpus:
        _write_json(out / "split.json", corpus_plan.split_document(rows, spec, out_fps))
        _write_json(out / "summary.json", summary)
    if as_json:
        emit_json(summary)
    elif len(jobs) > 1 or report.succeeded or corpus:  # one file that failed: its error says it
        _print_summary(summary)
    report.exit()


def _skeleton_inputs(inputs, asf):
    """The inputs less an ``.asf`` among them, and the skeleton (that ``.asf`` or --asf)."""
    asf_inputs = [p for p in inputs if is_kind(p, ".asf")]
    inputs = [p for p in inputs if not is_kind(p, ".asf")]
    if asf_inputs:
        if asf is not None or len(asf_inputs) > 1:
            raise InputError("give one skeleton: an .asf input or --asf, not several")
        asf = asf_inputs[0]
    if asf is not None:
        check_named_file(Path(asf), "skeleton")
    if not inputs and asf_inputs:
        raise InputError(f"{asf_inputs[0]} is a skeleton only: give the .amc motions too")
    return inputs, asf


def _plan(inputs, out: Path, out_arg, asf, source_fps, corpus: bool, split_file):
    """The import's jobs, the corpus files skipped (with why) and the split spec (None
    without --corpus); InputError before anything is read."""
    skipped: list[dict] = []
    spec = None
    if corpus:
        if not inputs or not all(p.is_dir() for p in inputs):
            raise InputError("--corpus takes corpus folders (CMU and/or HDM05)")
        if asf is not None or source_fps is not None:
            raise InputError("--corpus sets skeletons and frame rates itself: drop --asf, "
                             "--source-fps")  # fmt: skip
        if any(out.exists() and out.resolve() == p.resolve() for p in inputs):
            raise InputError("the output folder is a corpus folder; choose another")
        if len({p.resolve().name for p in inputs}) != len(inputs):
            raise InputError("two corpus folders have the same name; give each once")
        spec = corpus_plan.load_split_spec(split_file, cmu.default_split())
        jobs = []
        for item in plan_corpora(inputs, spec):
            if item.skip:
                skipped.append({"file": item.relpath.as_posix(), "reason": item.skip})
            else:
                jobs.append(FileJob(item.relpath, item.path, out / _output_name(item.relpath),
                                    data=item))  # fmt: skip
    else:
        if split_file is not None:
            raise InputError("--split only goes with --corpus")
        jobs = plan_jobs(inputs, out_arg, suffixes=SUFFIXES, rename=_output_name)
    outputs = [j.output for j in jobs]
    if len(set(outputs)) != len(outputs):
        dup = next(o for o in outputs if outputs.count(o) > 1)
        raise InputError(f"two inputs would both be written to {dup}; import them separately")
    return jobs, skipped, spec


def _run(jobs: list[FileJob], args: tuple, jobs_n: int):
    """Import every job (in ``jobs_n`` worker processes when more than one), a line per good
    file. -> the batch report"""
    from mdvae_cli.run.import_files import FileImporter

    pool = None
    if jobs_n > 1 and len(jobs) > 1:
        pool = ProcessPoolExecutor(min(jobs_n, len(jobs)), mp_context=get_context("spawn"),
                                   initializer=_start_worker, initargs=args)  # fmt: skip
        futures = {id(job): pool.submit(_work, job) for job in jobs}

        def process(job: FileJob) -> dict:
            return futures[id(job)].result()
    else:
        process = FileImporter(*args)

    def show(outcome) -> None:
        r = outcome.result
        what = (f"{r['tracks']} track(s), no retarget" if "tracks" in r
                else f"joint error {r['retarget_error_mm']:.1f} mm")  # fmt: skip
        console.print(f"{escape(outcome.job.relpath.as_posix())}: {r['frames']} frames at "
                      f"{r['fps']:g} fps, {what}", soft_wrap=True, highlight=False)  # fmt: skip

    try:
        return run_batch(jobs, process, "import", quiet=True, on_success=show)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)


COMMANDS = [import_command]
