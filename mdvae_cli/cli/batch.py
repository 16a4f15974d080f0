"""Run one function over many input files: output planning, progress, per-file failures.

Every file command (add-noise, eval, export-mesh, denoise, import) follows the same contract:

* inputs are files and/or folders; a folder contributes every matching file below it, and its
  tree is mirrored under the output folder (:func:`plan_jobs`);
* a file that fails prints one ``error: <file>: <why>`` line and the run goes on; the command
  exits 1 when any file failed (:func:`run_batch`, :meth:`BatchReport.exit`);
* ``--json`` puts one JSON document on stdout and nothing else there (:func:`emit_json`);
  human-readable output stays on the shared stderr console.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
from rich.markup import escape

from mdvae_cli.cli.common import console, os_error_words, progress_bar
from mdvae_cli.errors import InputError, MdvaeError
from mdvae_cli.fileio import MOTION_SUFFIXES, expand_inputs
from mdvae_cli.run.jobs import FileJob


@dataclass
class FileOutcome:
    """What happened to one job: ``result`` (whatever the function returned) or ``error``."""

    job: FileJob
    result: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: file, input, output, ok, error, result (``to_dict()`` of it if any)."""
        result = self.result
        if hasattr(result, "to_dict"):
            result = result.to_dict()
        return {
            "file": self.job.relpath.as_posix(),
            "input": str(self.job.source),
            # a failed file wrote nothing: no output to list
            "output": None if self.job.output is None or not self.ok else str(self.job.output),
            "ok": self.ok,
            "error": self.error,
            "result": result if self.ok else None,
        }


@dataclass
class BatchReport:
    outcomes: list[FileOutcome] = field(default_factory=list)

    @property
    def succeeded(self) -> list[FileOutcome]:
        return [o for o in self.outcomes if o.ok]

    @property
    def failed(self) -> list[FileOutcome]:
        return [o for o in self.outcomes if not o.ok]

    @property
    def exit_code(self) -> int:
        return 1 if self.failed else 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "files": [o.to_dict() for o in self.outcomes],
            "succeeded": len(self.succeeded),
            "failed": len(self.failed),
        }

    def print_summary(self, description: str) -> None:
        """``<description>: N of M files done[, K failed]`` on the console."""
        n_bad = len(self.failed)
        tail = f", [red]{n_bad} failed[/]" if n_bad else ""
        console.print(
            f"{description}: {len(self.succeeded)} of {len(self.outcomes)} files done{tail}"
        )

    def exit(self) -> None:
        """End the command with exit code 1 when any file failed (returns otherwise)."""
        if self.failed:
            sys.exit(1)


def strip_gz(relpath: Path) -> Path:
    """``a/b.npz.gz`` -> ``a/b.npz`` (outputs are written uncompressed)."""
    return relpath.with_suffix("") if relpath.suffix.lower() == ".gz" else relpath


def is_kind(path: Path, suffix: str) -> bool:
    """Whether ``path``'s name ends in ``suffix`` (any case), compressed (``.gz``) or not."""
    return path.name.lower().removesuffix(".gz").endswith(suffix)


def plan_jobs(
    inputs: Sequence[Path],
    out: Path | str | None,
    suffixes: tuple[str, ...] = MOTION_SUFFIXES,
    out_suffix: str | None = ".npz",
    rename: Callable[[Path], Path] | None = None,
    several: bool = False,
) -> list[FileJob]:
    """Expand ``inputs`` (files/folders) into jobs and choose each output path.
    several: the inputs are what is left of several given (so never one file's output name).

    With ``out_suffix`` (file outputs): one input file and an ``out`` ending in ``out_suffix``
    (any case) writes exactly ``out``; otherwise ``out`` is a folder and each output is
    ``out/relpath`` (``rename(relpath)`` when given). An ``out`` given as a string ending in a
    slash is always a folder. With ``out_suffix=None`` (folder outputs, e.g. meshes): one
    input file writes into ``out`` itself, several into ``out/<relpath without suffix>``.
    Files below ``out`` are not taken from an input folder that holds it; a broken link in an
    input folder is skipped with a ``note:`` line (:func:`expand_inputs`). Among several
    inputs, one that does not exist becomes a job of its own, which fails with one line while
    the others go on (:func:`run_batch`). Raises InputError for no inputs, no matching files,
    inputs that all do not exist, an output that is an input (file or folder), two inputs with
    one output, a ``.gz`` output name for one input file, or a file where a folder is needed:
    before anything is read.
    """
    if not inputs:
        raise InputError("no input files given")
    given, missing = list(inputs), [Path(p) for p in inputs if not Path(p).exists()]
    if missing and len(missing) < len(given):
        inputs = [p for p in given if Path(p).exists()]
        return [*plan_jobs(inputs, out, suffixes, out_suffix, rename, several=True),
                *(_missing_job(m, out, out_suffix, rename) for m in missing)]  # fmt: skip
    as_folder = out is not None and str(out).endswith(("/", os.sep))
    out = None if out is None else Path(out)
    for item in inputs:
        if out is not None and Path(item).is_dir() and out.resolve() == Path(item).resolve():
            raise InputError(f"the output folder {out} is an input folder; choose another")
    notes: list[str] = []
    items = expand_inputs(inputs, suffixes, skip=() if out is None else (out,), notes=notes)
    print_found_notes(notes)
    if not items:
        names = ", ".join(str(p) for p in inputs)
        raise InputError(f"no {'/'.join(suffixes)} files found in {names}")
    if out is None:
        return [FileJob(rel, src) for src, rel in items]
    single = len(items) == 1 and all(Path(p).is_file() for p in inputs) and not several
    if single and not as_folder and not out.is_dir():
        refuse_unsupported(out)

    if out_suffix is None:
        if single:
            return no_clashes([FileJob(items[0][1], items[0][0], out)])
        return no_clashes(
            [FileJob(rel, src, out / strip_gz(rel).with_suffix("")) for src, rel in items]
        )

    named = out.suffix.lower() == out_suffix and not as_folder  # any case, as inputs are found
    if single and named:
        return no_clashes([FileJob(items[0][1], items[0][0], out)])
    if single and not as_folder and not out.is_dir():
        refuse_gz(out, out_suffix)
        refuse_file_name(out, f"a file ending in {out_suffix}")
        if out.exists():
            raise InputError(
                f"the output {out} is a file that is not {out_suffix}: name an {out_suffix} "
                "file or a folder"
            )
    if (out.exists() and not out.is_dir()) or (not out.exists() and named):
        raise InputError(f"with a folder or several inputs, the output {out} must be a folder")
    rename = rename or strip_gz
    return no_clashes([FileJob(rel, src, out / rename(rel)) for src, rel in items])


def _missing_job(path: Path, out, out_suffix: str | None, rename) -> FileJob:
    """The job of an input that does not exist (it fails in :func:`run_batch`)."""
    rel = Path(path.name)
    if out is None:
        return FileJob(rel, path, missing=True)
    target = strip_gz(rel).with_suffix("") if out_suffix is None else (rename or strip_gz)(rel)
    return FileJob(rel, path, Path(out) / target, missing=True)


def refuse_unsupported(out: Path) -> None:
    """InputError when the output name ``out`` is in a format mdvae does not write (FBX, C3D,
    ..., or a video pipeline's pickle for an input that is not one): it would otherwise be
    taken for a folder name (``-o clean.pkl`` made a folder ``clean.pkl/`` holding
    ``take.npz``)."""
    from mdvae_cli.formats.registry import VIDEO_SUFFIXES, suffix_of, unsupported

    kind = suffix_of(out)
    if unsupported(out) is not None:
        raise InputError(
            f"cannot write {out}: mdvae does not write {kind[1:].upper()}; write .npz "
            "or .bvh (Blender, Maya and MotionBuilder import BVH and save it as FBX)"
        )
    if kind in VIDEO_SUFFIXES and not out.is_dir():
        npz = out.with_name(Path(out.name.removesuffix(".gz")).stem + ".npz")
        raise InputError(
            f"cannot write {out}: mdvae writes {kind[1:].upper()} only back for a video "
            f"pipeline's file of that form; name the output {npz}, or a folder"
        )


def refuse_file_name(out: Path, what: str) -> None:
    """InputError for one input's output named as a file of another kind (``clean.txt``,
    ``out.json``: a suffix of letters, not ``what`` the command writes): it would be taken for
    a folder name and the result written inside it. A trailing slash asks for such a folder."""
    suffix = out.suffix
    if 1 < len(suffix) <= 6 and suffix[1:].isalpha() and not out.exists():
        kind = ("is not what this command writes" if suffix.lower() in (".bvh", ".amc", ".npz")
                else "is not a motion file mdvae writes")  # fmt: skip
        raise InputError(
            f"cannot write {out}: {suffix} {kind}; name {what}, or end the name with / for a folder"
        )


def refuse_gz(out: Path, suffix: str = ".npz") -> None:
    """InputError when the output file name ``out`` ends in ``.gz``: what is written is a plain
    ``suffix`` file, which a ``.gz`` name would hide from every reader."""
    if out.suffix.lower() == ".gz":
        name = out.stem if out.stem.lower().endswith(suffix) else out.stem + suffix
        raise InputError(f"mdvae writes {suffix}, not .gz: name the output {out.with_name(name)}")


def no_clashes(jobs: list[FileJob]) -> list[FileJob]:
    """``jobs`` unchanged, or InputError when an output is one of the inputs (inputs are never
    overwritten) or when two inputs would be written to one output (e.g. ``a/take.npz`` and
    ``b/take.npz`` given as two folders' contents into one output folder)."""
    inputs = {job.source.resolve() for job in jobs}
    seen: dict[str, FileJob] = {}
    for job in jobs:
        if job.output.resolve() in inputs:
            raise InputError(
                f"refusing to overwrite the input file {job.output}: choose another -o"
            )
        key = os.path.normcase(os.path.abspath(job.output))
        if key in seen:
            raise InputError(
                f"{seen[key].source} and {job.source} would both be written to {job.output}; "
                "rename one, give a folder that holds both, or run them separately"
            )
        seen[key] = job
    return jobs


def _message(job: FileJob, exc: BaseException) -> str:
    if isinstance(exc, MdvaeError):
        text = str(exc)
    elif isinstance(exc, OSError):
        text = os_error_words(exc)
    else:
        text = f"{type(exc).__name__}: {exc}"
    text = " ".join(text.split())  # one line
    named = [str(job.source)] + ([str(job.data)] if isinstance(job.data, Path) else [])
    if any(name in text for name in named):
        return text
    blamed = text.split(": ", 1)[0]
    if blamed != text and Path(blamed).is_file():  # another file is at fault (an .asf, a map)
        return f"{text} (reading {job.source})"
    return f"{job.source}: {text}"


def _inside(progress, task, name: str) -> Callable[[int, int], None]:
    """``tell(done, total)`` for the bar of the progress inside one file."""

    def tell(done: int, total: int) -> None:
        progress.update(task, visible=True, completed=done, total=total, description=f"  {name}")

    return tell


def run_batch(
    jobs: Sequence[FileJob],
    fn: Callable[[FileJob], Any],
    description: str,
    quiet: bool = False,
    on_success: Callable[[FileOutcome], None] | None = None,
    within: bool = False,
) -> BatchReport:
    """Call ``fn(job)`` for each job, with a progress bar; collect results and failures.
    ``within``: call ``fn(job, tell)`` instead, ``tell(done, total)`` showing the progress
    inside that file (a long take) on a second bar.

    A failing job (any exception but KeyboardInterrupt) prints one ``error: ...`` line and
    the loop goes on; MDVAE_DEBUG=1 re-raises instead, for a traceback. ``on_success`` is
    called after each good job (e.g. to print a line). With several jobs a summary line
    follows, unless ``quiet``.
    """
    report = BatchReport()
    debug = bool(os.environ.get("MDVAE_DEBUG"))
    with progress_bar() as progress:
        task = progress.add_task(description, total=len(jobs), info="")
        inner = progress.add_task("", total=1, visible=False, info="") if within else None
        for job in jobs:
            progress.update(task, info=escape(job.relpath.as_posix()))
            try:
                if job.missing:  # one of several inputs named
                    raise InputError(f"no such file or folder: {job.source}")
                if inner is None:
                    outcome = FileOutcome(job, result=fn(job))
                else:
                    tell = _inside(progress, inner, job.relpath.name)
                    outcome = FileOutcome(job, result=fn(job, tell))
                    progress.update(inner, visible=False)
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                if debug:
                    raise
                outcome = FileOutcome(job, error=_message(job, exc))
                console.print(f"[bold red]error:[/] {escape(outcome.error)}", soft_wrap=True)
            else:
                if on_success is not None:
                    on_success(outcome)
            report.outcomes.append(outcome)
            progress.advance(task)
    if len(jobs) > 1 and not quiet:
        report.print_summary(description)
    return report


def print_found_notes(notes: Iterable[str]) -> None:
    """Show what finding the inputs skipped (a broken link in a folder) as ``note:`` lines."""
    for note in notes:
        console.print(f"[dim]note: {escape(note)}[/]", soft_wrap=True)


def note_broken_links(paths: Iterable[Path | str]) -> None:
    """``note:`` lines for the broken links in the folders among ``paths`` (a training run's
    data: the trainer skips them); a missing path is left for the trainer to report."""
    notes: list[str] = []
    for path in paths:
        with contextlib.suppress(InputError):
            expand_inputs([Path(path)], notes=notes)
    print_found_notes(notes)


def print_notes(relpath: Path, notes: Iterable[str]) -> None:
    """Show remarks made while reading a file (e.g. padded betas) as dim ``note:`` lines; a
    remark that starts with ``warning: `` (the output will differ from the file) as a
    ``warning:`` line."""
    for note in notes:
        where = escape(relpath.as_posix())
        if note.startswith("warning: "):
            text = escape(note.removeprefix("warning: "))
            console.print(f"[yellow]warning:[/] {where}: {text}", soft_wrap=True)
        else:
            console.print(f"[dim]note: {where}: {escape(note)}[/]", soft_wrap=True)


def emit_json(data: Any) -> None:
    """Write one JSON document to stdout (the only thing a --json run puts there)."""
    click.echo(json.dumps(data, indent=2, allow_nan=False))


def json_option(fn: Callable) -> Callable:
    """``--json``: machine-readable results on stdout."""
    return click.option(
        "--json", "as_json", is_flag=True, help="Print results as JSON on stdout (for pipelines)."
    )(fn)
