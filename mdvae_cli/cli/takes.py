"""Mocap takes (BVH, ASF/AMC) in file commands: which output form each input gets, and a
reader that keeps what writing a take back needs (torch is loaded only when a take is read)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from mdvae_cli.cli.batch import FileJob, is_kind, no_clashes, plan_jobs, refuse_gz, strip_gz
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.motion.load_any import MOTION_FILE_SUFFIXES

#: what ``mdvae denoise`` reads: AMASS-style .npz, mocap takes, video pipelines' outputs
DENOISE_SUFFIXES = (*MOTION_FILE_SUFFIXES, ".bvh", ".amc")

#: the output form of each input form: takes come back in their own, everything else as .npz
_FORM = {**{s: ".npz" for s in MOTION_FILE_SUFFIXES}, ".bvh": ".bvh", ".amc": ".amc"}


def is_take(path: Path | None) -> bool:
    """Whether ``path`` names a mocap take (.bvh, .amc, .gz too) rather than an .npz."""
    return path is not None and (is_kind(path, ".bvh") or is_kind(path, ".amc"))


def _form(path: Path) -> str:
    return next(s for s in _FORM if is_kind(path, s))


def output_name(relpath: Path) -> Path:
    """A folder output's name: the input's, uncompressed, in the input's output form."""
    plain = strip_gz(relpath)
    return plain.with_suffix(_FORM[_form(relpath)])


def _wrong_form(src: Path, form: str, wants: str) -> str:
    """Why ``src`` (of ``form``) cannot be written as ``wants`` (.bvh or .amc), in one line."""
    what = {".bvh": "a BVH", ".amc": "an AMC", ".npz": "an .npz"}
    forms = ".npz" if form == ".npz" else f"{form} or .npz"
    hint = " (mdvae export-bvh turns an .npz into BVH on the SMPL skeleton)"
    return (f"{src} is {what[form]} file, not {what[wants]} take: write it as {forms}"
            + (hint if wants == ".bvh" and form == ".npz" else ""))  # fmt: skip


def plan_take_jobs(inputs, out) -> list[FileJob]:
    """:func:`plan_jobs` for inputs of several forms: one input file may be written to a named
    ``.npz`` (any input), ``.bvh``/``.bvh.gz`` (a BVH input) or ``.amc``/``.amc.gz`` (an AMC
    input); folders mirror each input in its own form. InputError for a form the input cannot
    take."""
    as_folder = str(out).endswith(("/", os.sep))
    out = Path(out)
    if len(inputs) == 1 and Path(inputs[0]).is_file() and not as_folder and not out.is_dir():
        src = Path(inputs[0])
        name = out.name.lower()
        ends = (".bvh.gz", ".bvh", ".amc.gz", ".amc", ".npz")
        wants = next((s for s in ends if name.endswith(s)), "").removesuffix(".gz")
        if wants and any(is_kind(src, s) for s in DENOISE_SUFFIXES):
            form = _FORM[_form(src)]
            if wants != ".npz" and wants != form:
                raise InputError(_wrong_form(src, form, wants))
            return no_clashes([FileJob(Path(src.name), src, out)])
        if name.endswith(".gz"):
            refuse_gz(out)
    return plan_jobs(inputs, str(out) + ("/" if as_folder else ""), DENOISE_SUFFIXES,
                     rename=output_name)  # fmt: skip


def load_joint_map(path: Path | str | None) -> dict[str, str] | None:
    """A ``--joint-map`` JSON file: {"left_hip": "LeftUpLeg", ...} (SMPL joint -> source)."""
    if path is None:
        return None
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the joint map ({exc})") from None
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in data.items()
    ):
        raise InputError(f'{path}: a joint map is a JSON object {{"left_hip": "LeftUpLeg", ...}}')
    return data


class TakeReader:
    """Reads takes for a command: the body's joints once, each ASF once, betas once per
    skeleton; keeps every take read (by input path) for writing back."""

    def __init__(self, body_model, asf: Path | None, joint_map: dict | None):
        self.body_model, self.asf, self.joint_map = body_model, asf, joint_map
        self._body = None
        self.skeletons: dict = {}
        self.betas: dict = {}
        self.takes: dict = {}
        self.found_asf: dict = {}  # AMC input -> the skeleton found next to it

    @property
    def body(self):
        if self._body is None:
            from mdvae_cli.body.formats import load_body_model
            from mdvae_cli.motion.fit_shape import BodyJoints

            self._body = BodyJoints(load_body_model(self.body_model))
        return self._body

    def __call__(self, job: FileJob):
        """Read and retarget one take.  -> motion.take.Take"""
        from mdvae_cli.cli.import_worker import find_asf
        from mdvae_cli.motion.asf import load_asf
        from mdvae_cli.motion.fit_shape import fit_betas, skeleton_key
        from mdvae_cli.motion.retarget import load_source
        from mdvae_cli.motion.take import read_take

        skeleton = None
        if is_kind(job.source, ".amc"):
            skeleton = self.asf or find_asf(job.source)
            if skeleton is None:
                raise InputError(f"{job.source}: no skeleton found next to it; pass --asf FILE")
            if self.asf is None:
                self.found_asf[job.source] = skeleton
            if skeleton not in self.skeletons:
                self.skeletons[skeleton] = load_asf(skeleton)
            skeleton = self.skeletons[skeleton]
        src = load_source(job.source, skeleton, joint_map=self.joint_map)
        key = skeleton_key(src)
        if key not in self.betas:
            try:
                self.betas[key] = fit_betas(src, self.body)
            except InputError as exc:
                raise InputError(f"{job.source}: {exc}") from None
        take = read_take(job.source, self.body, betas=self.betas[key], source=src)
        self.takes[job.source] = take
        return take

    def write(self, job: FileJob, cleaned, forbid: tuple = ()) -> None:
        """Write the cleaned SMPL motion of ``job``'s take back on its own skeleton. An AMC
        take whose skeleton was found next to it gets a copy of that ``.asf`` next to its
        output when none of that name is there, so the output reads on its own."""
        from mdvae_cli.motion.take import write_take

        write_take(self.takes[job.source], cleaned, job.output, self.body, forbid=forbid)
        asf = self.found_asf.get(job.source)
        if asf is not None and is_kind(job.output, ".amc"):
            copy = Path(job.output).parent / Path(asf).name
            if not copy.exists():
                write_atomic(copy, lambda tmp: shutil.copyfile(asf, tmp), forbid=forbid)
