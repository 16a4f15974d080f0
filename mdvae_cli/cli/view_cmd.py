"""``mdvae view`` (one self-contained HTML page that plays motions side by side) and
``mdvae plot`` (a static before/after figure, PNG or SVG)."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.markup import escape

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    json_option,
    print_found_notes,
    print_notes,
    run_batch,
)
from mdvae_cli.cli.common import (
    OutputPath,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.motion_input import input_fps_option, one_track, track_option
from mdvae_cli.cli.takes import read_ahead, take_options, take_reading
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import expand_inputs


def motion_labels(paths: list[Path]) -> list[str]:
    """Each file's label: its name, with as many parent folders as it takes to tell the
    files apart (``a/take.npz``, ``b/take.npz``)."""
    paths = [Path(p) for p in paths]
    for depth in range(1, max(len(p.parts) for p in paths) + 1):
        labels = ["/".join(p.parts[-depth:]) for p in paths]
        if len(set(labels)) == len(labels):
            return labels
    return [f"{i + 1}: {p.name}" for i, p in enumerate(paths)]


def read_motions(
    inputs, body_data, asf, joint_map_file, allow_pickle, out: Path, fps=None, track=None,
    ahead=None,
):  # fmt: skip
    """The report of reading every input file (folders: every motion file below them, in
    order) with a progress bar, and (label, Motion) for each file read: the track ``track``
    names (``--track``) of a file of several people, else its first, said in a note. A file
    that cannot be read is one ``error:`` line. fps: ``--fps``, the inputs' frame rate
    (None: each file's own). ahead: takes already being read (``cli.takes.read_ahead``)."""
    from mdvae_cli.formats.registry import READ_SUFFIXES, ReadOptions, read
    from mdvae_cli.retarget.take import TakeReader

    options = ReadOptions(allow_pickle=allow_pickle, body=body_data, fps=fps,
                          **take_reading(asf, joint_map_file))  # fmt: skip
    takes = TakeReader(body_data, options.skeleton, options.joint_map, ahead=ahead)
    notes: list[str] = []
    given = [Path(p) for p in inputs]  # one missing path of several fails alone, as a bad file
    missing = [p for p in given if not p.exists()] if len(given) > 1 else []
    found = [p for p in given if p.exists()] or given
    files = [src for src, _ in expand_inputs(found, READ_SUFFIXES, skip=(out,), notes=notes)]
    print_found_notes(notes)
    if not files:
        raise InputError(f"no motion files found in {', '.join(str(p) for p in inputs)}")
    jobs = [FileJob(Path(label), src) for src, label in zip(files, motion_labels(files),
                                                                strict=True)]  # fmt: skip
    jobs += [FileJob(Path(p.name), p, missing=True) for p in missing if found != given]

    def one(job: FileJob):
        loaded = read(job.source, options, takes=takes)
        label, motion = loaded.tracks[0]
        if track is not None and len(loaded.tracks) > 1:
            label, motion = str(track), one_track(loaded, track)
        elif track is not None and loaded.document is not None:  # a pipeline's one person
            own = loaded.document.tracks[0][1].label
            if own is not None and str(own) != str(track):
                raise InputError(f"{job.source}: no track {track!r} (tracks: {own})")
        notes = [*loaded.notes, *motion.notes]
        if len(loaded.tracks) > 1:
            others = ", ".join(str(lab) for lab, _ in loaded.tracks if lab != label)
            notes.append(f"{len(loaded.tracks)} people tracked: showing track {label} "
                         f"(--track for {others})")  # fmt: skip
        print_notes(job.relpath, notes)
        return motion, (f" track {label}" if len(loaded.tracks) > 1 else "")

    report = run_batch(jobs, one, "reading", quiet=True)
    return report, [(o.job.relpath.as_posix() + o.result[1], o.result[0])
                    for o in report.succeeded]  # fmt: skip


def check_output(out: Path, suffixes: tuple[str, ...], inputs) -> None:
    if out.suffix.lower() not in suffixes:
        raise InputError(f"the output {out} must end in {' or '.join(suffixes)}")
    for p in inputs:
        if Path(p).exists() and Path(p).resolve() == out.resolve():
            raise InputError(f"refusing to overwrite the input file {p}")


def inputs_argument(fn):
    return click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))(fn)


@click.command("view")
@inputs_argument
@click.option(
    "-o", "--out", type=OutputPath(path_type=Path), required=True,
    help="The .html page to write.",
)  # fmt: skip
@click.option(
    "--mesh/--no-mesh", default=True, show_default=True,
    help="Embed a skinned low-poly body mesh as well as the skeleton (a few kB).",
)  # fmt: skip
@click.option("--title", default=None, help="The page's title (default: the file names).")
@take_options
@input_fps_option
@track_option("show this track (its id in the file)", "shows its first track")
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def view(
    inputs, out, mesh, title, asf, joint_map_file, input_fps, track, body_model, allow_pickle,
    as_json,
):  # fmt: skip
    """Write one self-contained HTML page that plays motions side by side or overlaid.

    INPUTS are motion files in any format mdvae reads (.npz, .bvh, .amc, video pipelines'
    outputs; .gz too) or folders of them (every motion file below, in order), e.g. a
    noisy take, its cleaned version and the ground truth. The page works offline in any
    current browser, with no server: play / pause, a timeline to scrub, speed, an orbiting
    camera (drag, wheel), side-by-side or overlay, skeleton and a low-poly body mesh, foot
    contacts marked, and a plot of a chosen joint's angle, height or speed for every motion.
    Motions of different lengths and frame rates are aligned by time.

    \b
    Examples:
      mdvae view noisy.npz clean.npz -o compare.html
      mdvae view noisy.npz clean.npz gt.npz studio.bvh -o compare.html --no-mesh
    """
    out = Path(out)
    check_output(out, (".html", ".htm"), inputs)
    ahead = read_ahead(inputs, input_fps, joint_map_file)  # before torch loads
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.view.page import build_view_page, write_view_page

    body_data = load_body_model(body_model)
    report, items = read_motions(inputs, body_data, asf, joint_map_file, allow_pickle, out,
                                 input_fps, track, ahead)  # fmt: skip
    if not items:
        _nothing_read(report, as_json)
    page = build_view_page(items, BodyModel(body_data), mesh=mesh, title=title)
    write_view_page(page, out, forbid=tuple(inputs))
    summary = {"output": str(out), "bytes": page.num_bytes, "mesh": page.mesh,
               "motions": page.motions, **_read_counts(report)}  # fmt: skip
    if as_json:
        emit_json(summary)
    else:
        frames = sum(m["frames"] for m in page.motions)
        console.print(
            f"wrote {escape(str(out))} ({page.num_bytes / 1e6:.2f} MB, {len(items)} motion(s), "
            f"{frames} frame{'s' * (frames != 1)}"
            f"{', skeleton only' if not page.mesh else ''})"
        )
    report.exit()


def _nothing_read(report, as_json: bool) -> None:
    """End a command none of whose inputs could be read (each said why in its ``error:``
    line): exit 1, with --json its summary on stdout (nothing written)."""
    if as_json:
        emit_json({"ok": False, "output": None, "motions": [], **_read_counts(report)})
    sys.exit(1)


def _read_counts(report) -> dict:
    """The files that could not be read (they are left out of the output), for --json."""
    errors = [{"file": str(o.job.source), "error": o.error} for o in report.failed]
    return {"failed": len(report.failed), "errors": errors}


@click.command("plot")
@inputs_argument
@click.option(
    "-o", "--out", type=OutputPath(path_type=Path), required=True,
    help="The figure to write: .png, or .svg for a vector figure.",
)  # fmt: skip
@click.option(
    "--joint", "joints", multiple=True, default=("left_knee", "right_knee"), show_default=True,
    help="A joint to plot (name or index of the 22 SMPL body joints); repeat for more panels.",
)  # fmt: skip
@click.option(
    "--series", type=click.Choice(["rotation", "bend", "height", "speed"]), default="rotation",
    show_default=True,
    help="What to plot: the joint angle, its rotation from its parent (rotation); the angle "
    "between the bones into and out of it (bend); its height (m) or speed (m/s).",
)  # fmt: skip
@click.option(
    "--frames", type=click.IntRange(1, 20), default=6, show_default=True,
    help="Frames in the filmstrip (evenly spread over the take).",
)  # fmt: skip
@click.option(
    "--width", type=click.IntRange(400, 8000), default=1400, show_default=True,
    help="Figure width in pixels.",
)  # fmt: skip
@click.option("--title", default=None, help="The figure's title (default: the file names).")
@take_options
@input_fps_option
@track_option("draw this track (its id in the file)", "shows its first track")
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def plot(
    inputs, out, joints, series, frames, width, title, asf, joint_map_file, input_fps, track,
    body_model, allow_pickle, as_json,
):  # fmt: skip
    """Draw a static before/after figure: joint curves over time, foot contacts and a
    filmstrip of a few frames for every motion (for reports).

    INPUTS are motion files in any format mdvae reads (or folders of them), drawn in this
    order and colour.
    Drawn with matplotlib (pip install 'mdvae[plot]'): a PNG, or an SVG when -o ends in .svg.

    \b
    Examples:
      mdvae plot noisy.npz clean.npz -o before_after.png
      mdvae plot noisy.npz clean.npz gt.npz -o fig.svg --joint left_hip --series bend
    """
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.fileio import write_atomic
    from mdvae_cli.view.figure import (
        FigureSpec,
        draw_figure,
        figure_bytes,
        figure_size,
        joint_index,
        require_matplotlib,
    )

    out = Path(out)
    check_output(out, (".png", ".svg"), inputs)
    require_matplotlib()  # before anything is read
    spec = FigureSpec(
        joints=tuple(joint_index(j) for j in joints), series=series, frames=frames,
        width=width, title=title,
    ).validate()  # fmt: skip
    body_data = load_body_model(body_model)
    report, items = read_motions(inputs, body_data, asf, joint_map_file, allow_pickle, out,
                                 input_fps, track)  # fmt: skip
    if not items:
        _nothing_read(report, as_json)
    figure = draw_figure(items, BodyModel(body_data), spec)
    data = figure_bytes(figure, out.suffix.lower()[1:])
    write_atomic(out, lambda tmp: tmp.write_bytes(data), forbid=tuple(inputs))
    width, height = figure_size(figure)
    if as_json:
        emit_json({"output": str(out), "bytes": len(data), "width": width, "height": height,
                   "motions": [label for label, _ in items], **_read_counts(report)})  # fmt: skip
    else:
        console.print(f"wrote {escape(str(out))} ({width} x {height}, {len(data) / 1e3:.0f} kB)")
    report.exit()


COMMANDS = [view, plot]
