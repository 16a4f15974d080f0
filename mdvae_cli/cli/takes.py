"""Mocap takes (BVH, ASF/AMC) in file commands: which output form each input gets, and the
``--asf`` and ``--joint-map`` options."""

from __future__ import annotations

import atexit
import json
import os
from pathlib import Path

import click

from mdvae_cli.cli.batch import (
    FileJob,
    is_kind,
    no_clashes,
    plan_jobs,
    refuse_file_name,
    refuse_gz,
    refuse_unsupported,
    strip_gz,
)
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_named_file, check_regular, entry_of
from mdvae_cli.formats.registry import READ_SUFFIXES, VIDEO_SUFFIXES, unsupported

#: what ``mdvae denoise`` reads: AMASS-style .npz, mocap takes, video pipelines' outputs
DENOISE_SUFFIXES = READ_SUFFIXES

#: the output form of each input form: each its own (a video pipeline's file whose format
#: mdvae does not write back becomes .npz once read: ``run.tracks.own_output``)
_FORM = {s: s for s in READ_SUFFIXES}
#: the names a video pipeline's file may be written back under, by its own name
_VIDEO_FAMILIES = ((".pkl", ".pk", ".pickle", ".joblib"), (".pt", ".pth"), (".npy",))


def is_take(path: Path | None) -> bool:
    """Whether ``path`` names a mocap take (.bvh, .amc, .gz too) rather than an .npz."""
    return path is not None and (is_kind(path, ".bvh") or is_kind(path, ".amc"))


def _form(path: Path) -> str:
    """The input form of ``path`` (its suffix among :data:`READ_SUFFIXES`); InputError for a
    name that says no form mdvae reads (no extension, ``take.txt``)."""
    form = next((s for s in _FORM if is_kind(path, s)), None)
    why = unsupported(path) if form is None else None
    if why is not None:  # a format of its own (FBX, C3D, a video): the way forward for it
        raise InputError(f"{path}: {why}")
    if form is None:
        raise InputError(
            f"{path}: its name says no form mdvae reads; name it for what it holds: .npz, "
            ".bvh or .amc (each also .gz), or a video pipeline's " + ", ".join(VIDEO_SUFFIXES)
        )
    return form


#: forms written gzipped when their name ends in .gz (the others are written plain)
_GZ_FORMS = (".bvh", ".amc")


def output_name(relpath: Path) -> Path:
    """A folder output's name: the input's, in the input's output form: a take's name as it
    came (``Walk.BVH``, ``zombie.bvh.gz``: written gzipped), any other's uncompressed
    (``a.npz.gz`` -> ``a.npz``)."""
    form = _FORM[_form(relpath)]
    plain = strip_gz(relpath)
    if form in _GZ_FORMS and plain.suffix.lower() == form:
        return relpath
    return plain.with_suffix(form)


def _same_form(form: str, wants: str) -> bool:
    """Whether an input of ``form`` may be written as ``wants``: .npz always, else its own
    form (a video pipeline's under any name of its family: res.pk -> clean.pkl)."""
    if wants in (".npz", form):
        return True
    return any(form in f and wants in f for f in _VIDEO_FAMILIES)


def _wrong_form(src: Path, form: str, wants: str) -> str:
    """Why ``src`` (of ``form``) cannot be written as ``wants``, in one line."""
    what = {".bvh": "a BVH take", ".amc": "an AMC take"}
    kind = what.get(form, f"a {form} file")
    forms = ".npz" if form == ".npz" else f"{form} or .npz"
    hint = " (mdvae export-bvh turns an .npz into BVH on the SMPL skeleton)"
    return (f"{src}: {kind}, not {what.get(wants, f'a {wants} file')}: write it as {forms}"
            + (hint if wants == ".bvh" and form == ".npz" else ""))  # fmt: skip


def plan_take_jobs(inputs, out) -> list[FileJob]:
    """:func:`plan_jobs` for inputs of several forms: one input file may be written to a named
    ``.npz`` (any input), ``.bvh``/``.bvh.gz`` (a BVH input), ``.amc``/``.amc.gz`` (an AMC
    input) or its own video pipeline form (``.pkl``, ``.pt``, ...: a file of that pipeline);
    folders mirror each input in its own form. InputError for a form the input cannot
    take."""
    as_folder = str(out).endswith(("/", os.sep))
    out = Path(out)
    for p in inputs:  # a file named on the command line: its name must say its form
        if Path(p).is_file():
            _form(Path(p))
    one = len({entry_of(p) for p in inputs}) == 1  # a path named twice is one input
    if one and Path(inputs[0]).is_file() and not as_folder and not out.is_dir():
        src = Path(inputs[0])
        name = out.name.lower()
        known = any(is_kind(src, s) for s in DENOISE_SUFFIXES)
        ends = (".bvh.gz", ".bvh", ".amc.gz", ".amc", ".npz",
                *(s + ".gz" for s in VIDEO_SUFFIXES), *VIDEO_SUFFIXES)  # fmt: skip
        wants = next((s for s in ends if name.endswith(s)), "").removesuffix(".gz")
        if not (known and wants in VIDEO_SUFFIXES and _form(src) in VIDEO_SUFFIXES):
            refuse_unsupported(out)
        if wants and known and not _same_form(_FORM[_form(src)], wants):
            raise InputError(_wrong_form(src, _FORM[_form(src)], wants))
        if wants in VIDEO_SUFFIXES and name.endswith(".gz"):
            refuse_gz(out, wants)
        if wants and known:
            return no_clashes([FileJob(Path(src.name), src, out)])
        if name.endswith(".gz"):
            refuse_gz(out)
        if not wants:
            refuse_file_name(out, "an .npz (any input), a .bvh or .amc (a take of that "
                             "form) or the input's own form")  # fmt: skip
    return plan_jobs(inputs, str(out) + ("/" if as_folder else ""), DENOISE_SUFFIXES,
                     rename=output_name)  # fmt: skip


#: bytes a ``--joint-map`` file may hold
MAX_JOINT_MAP = 1 << 20


def load_joint_map(path: Path | str | None) -> dict[str, str] | None:
    """A ``--joint-map`` JSON file: {"left_hip": "LeftUpLeg", ...} (SMPL joint -> source)."""
    if path is None:
        return None
    check_regular(Path(path))
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_JOINT_MAP + 1)
        if len(raw) > MAX_JOINT_MAP:
            raise InputError(f"{path}: over {MAX_JOINT_MAP >> 10} kB; a joint map is a few lines")
        data = json.loads(raw.decode("utf-8-sig"))
    except RecursionError:
        raise InputError(f"{path}: nested too deep; a joint map is one flat JSON object") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text; a joint map is a JSON file") from None
    except (OSError, ValueError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise InputError(f"{path}: cannot read the joint map ({why})") from None
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in data.items()
    ):
        raise InputError(f'{path}: a joint map is a JSON object {{"left_hip": "LeftUpLeg", ...}}')
    return data


def take_options(fn):
    """``--asf`` and ``--joint-map``: how BVH / AMC takes are read (as ``mdvae denoise``)."""
    fn = click.option(
        "--joint-map",
        "joint_map_file",
        type=click.Path(path_type=Path, dir_okay=False),
        help="For BVH/AMC takes whose joint names are not recognised: a JSON file naming them "
        '(SMPL joint -> yours, e.g. {"left_hip": "LeftUpLeg"}).',
    )(fn)
    return click.option(
        "--asf",
        type=click.Path(path_type=Path, dir_okay=False),
        default=None,
        help="The .asf skeleton of .amc inputs (default: the one next to each file).",
    )(fn)


def take_reading(asf: Path | None, joint_map_file: Path | None) -> dict:
    """``formats.registry.ReadOptions``' fields for :func:`take_options`' values: the
    skeleton (checked to be a file) and the joint map (read)."""
    if asf is not None:
        check_named_file(Path(asf), "skeleton")
    return {"skeleton": None if asf is None else Path(asf),
            "joint_map": load_joint_map(joint_map_file)}  # fmt: skip


#: input files whose reading goes ahead while torch loads (a process each)
READ_AHEAD_FILES = 2


def read_ahead(inputs, fps=None, joint_map_file=None, input_format=None):
    """Start reading the BVH takes among a command's first inputs (files named, not folders)
    while torch and the model load: each parse in a process of its own
    (``run.read_ahead``). -> a ``ReadAhead`` for the take reader, or None (nothing to read
    ahead, or the system cannot). ``fps``: ``--fps``; a ``--joint-map`` or ``--format`` keeps
    every read in this process."""
    from mdvae_cli.formats.registry import suffix_of
    from mdvae_cli.retarget.source_file import load_source
    from mdvae_cli.run.read_ahead import ReadAhead

    if joint_map_file is not None or input_format is not None:
        return None
    ahead = ReadAhead()
    for path in dict.fromkeys(Path(p) for p in inputs[:READ_AHEAD_FILES]):
        if path.is_file() and suffix_of(path) == ".bvh":
            if not ahead.start(load_source, path, None, fps=fps, scale=None, joint_map=None):
                break
    if not ahead:
        return None
    atexit.register(ahead.close)
    return ahead
