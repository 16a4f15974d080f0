"""The tracks of a file a command reads: where each is written, and putting one on the floor.

A file of several people (a WHAM or PHALP result with several tracks) gives one output per
track, named ``<output stem>.track<ID>.npz`` beside the output the file would have had; in
the pipeline's own form (``own_output``) all its tracks go back into one file.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.formats.loaded import LoadedFile
from mdvae_cli.motion.motion import Motion


def track_output(output: Path, label: str | None) -> Path:
    """Where one track of a file goes: ``output`` itself for a file of one motion, else
    ``<stem>.track<label><suffix>`` beside it (the label made file-name safe)."""
    if label is None:
        return output
    safe = re.sub(r"[^A-Za-z0-9_-]+", "_", str(label)) or "_"
    return output.with_name(f"{output.stem}.track{safe}{output.suffix}")


def outputs_of(
    loaded: LoadedFile, output: Path, holes: bool = False
) -> list[tuple[str | None, Motion, Path]]:
    """Each track of a file with its output path (all the same in the file's own form;
    ``holes``: as :func:`own_output`)."""
    own = own_output(loaded, output, holes)[1]
    return [(lab, m, output if own else track_output(output, lab)) for lab, m in loaded.tracks]


#: how a reader's note ends when it says what the AMASS-style .npz leaves out of a file
#: ("'verts' (made from the pose by any SMPL tool) not carried")
NOT_CARRIED = "not carried"


def reader_notes(notes: list[str], own: bool) -> list[str]:
    """A track's notes from its reader to tell the user: in the file's own form (``own``)
    without those saying what the .npz form leaves out, since writing the file back says
    what it leaves out itself (``formats.video_back``: "'verts' left out"), once."""
    return [n for n in notes if not (own and n.endswith(NOT_CARRIED))]


def own_output(
    loaded: LoadedFile, output: Path, holes: bool = False
) -> tuple[Path, bool, str | None]:
    """Where a video pipeline's file named for its own form (``.pkl``, ``.pt``, ...; ``.npz``
    for ROMP and SLAHMR, whose own file is one) goes: -> (output, True, None) when mdvae
    writes its format back in that form, else the ``.npz`` beside it, False and a note saying
    why. Any other output: (output, False, None). ``holes``: the tracks are written with
    holes (NaN), which only the AMASS-style ``.npz`` holds: an ``.npz`` output is that."""
    from mdvae_cli.formats.registry import VIDEO_SUFFIXES, suffix_of

    kind = suffix_of(output)
    if kind not in VIDEO_SUFFIXES and (kind != ".npz" or holes or loaded.document is None):
        return output, False, None
    from mdvae_cli.formats.video_back import writes_back

    if kind == ".npz":
        return output, writes_back(loaded.document, output), None
    if writes_back(loaded.document, output):
        return output, True, None
    npz = output.with_name(Path(output.name.removesuffix(".gz")).stem + ".npz")
    why = "not a video pipeline's file" if loaded.document is None else loaded.document.own_form()
    return npz, False, f"written as {npz.name} ({why})"


def floor_height(motion: Motion, body: BodyModelData, max_tilt: float = 0.035) -> float:
    """The height (m) of the ground under a motion's soles: the lower envelope of each frame's
    lowest foot vertex (``retarget.retarget.fit_ground`` without tilt), the motion posed on
    ``body``."""
    from mdvae_cli.export import pose_motion_chunks
    from mdvae_cli.retarget.fit_shape import BodyJoints
    from mdvae_cli.retarget.retarget import fit_ground

    feet = BodyJoints(body).foot_ids
    lowest = []
    for _, out in pose_motion_chunks(motion, body, vertices=True):
        v = out.vertices[:, feet].double().numpy()
        i = v[..., 2].argmin(axis=1)
        lowest.append(v[np.arange(len(v)), i])
    p = np.concatenate(lowest)
    return float(fit_ground(p[:, [0, 2, 1]], max_tilt, tilt=False)[0])


def on_floor(motion: Motion, body: BodyModelData, max_tilt: float = 0.035) -> Motion:
    """A copy of ``motion`` moved up or down so that the ground under its soles
    (:func:`floor_height`) is at z = 0, with a note saying by how much (``--floor``)."""
    h = floor_height(motion, body, max_tilt)
    out = motion.with_body(trans=motion.trans - [0.0, 0.0, h])
    out.notes.append(f"put on the floor (--floor): heights {-100 * h:+.1f} cm")
    return out
