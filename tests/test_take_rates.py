"""Studio takes at rates other than 30 Hz and ASF/AMC takes, in and out: frame counts, spans.

Real-data tests read excerpts of ``../shared/data/cmu`` (or ``$MDVAE_CMU_DATA``), written to
``tmp_path`` only, and are skipped where that folder is absent.
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.bvh import load_bvh

REPO = Path(__file__).resolve().parents[1]
CMU = Path(os.environ.get("MDVAE_CMU_DATA", REPO.parent / "shared" / "data" / "cmu"))
needs_cmu = pytest.mark.skipif(not (CMU / "bvh").is_dir() or not (CMU / "asfamc").is_dir(),
                               reason=f"no CMU data at {CMU}")  # fmt: skip


def run(*args) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def _cmuconvert_excerpt(path: Path, step: int, frames: int, frame_time: str) -> Path:
    """Every ``step``-th frame of a cmuconvert take from frame 1 on (its T-pose frame 0 left
    out), as a take of its own at another rate."""
    lines = gzip.open(CMU / "bvh/05_06.bvh.gz", "rt").read().splitlines()
    i = lines.index("MOTION")
    rows = lines[i + 4 :: step][:frames]
    text = [*lines[: i + 1], f"Frames: {len(rows)}", f"Frame Time: {frame_time}", *rows]
    path.write_text("\n".join(text) + "\n")
    return path


@needs_cmu
def test_cmuconvert_rig_keeps_a_frame_0_that_is_no_t_pose(tmp_path):
    """A 31-frame 24 fps take on the cmuconvert rig (trimmed, resampled) lost its frame 0 as
    if it were the release's added T-pose: 30 frames read, 37 at 30 Hz instead of 38."""
    take = _cmuconvert_excerpt(tmp_path / "walk24.bvh", 5, 31, "0.0416667")
    src = load_bvh(take)
    assert src.num_frames == 31 and not src.info["dropped_first_frame"]
    assert load_bvh(CMU / "bvh/05_06.bvh.gz", max_frames=3).info["dropped_first_frame"]

    code, _, err = run("import", take, "-o", tmp_path / "at30.npz")
    assert code == 0, err
    assert np.load(tmp_path / "at30.npz")["poses"].shape[0] == 38  # 1.25 s at 30 Hz
    code, _, err = run("import", take, "-o", tmp_path / "own.npz", "--fps", "0")
    assert code == 0, err
    own = np.load(tmp_path / "own.npz")
    assert own["poses"].shape[0] == 31 and float(own["mocap_framerate"]) == 24.0


def test_eval_at_two_rates_says_the_frame_it_does_not_score():
    """31 frames at 24 fps (1.25 s) against their import at 30 fps (38 frames, 1.233 s):
    scored at 24 fps, the truth's last frame lies past the prediction's end; it was dropped
    with no word (30 frames reported for a 31-frame take)."""
    from conftest import motion_arrays

    from mdvae_cli.formats.npz_io import motion_from_arrays
    from mdvae_cli.metrics import common_rate

    truth = motion_from_arrays(motion_arrays(T=31, fps=24.0))
    guess = motion_from_arrays(motion_arrays(T=38, fps=30.0))
    a, b, note = common_rate(truth, guess)
    assert a.num_frames == b.num_frames == 30 and a.fps == b.fps == 24.0
    assert note == (
        "evaluated at 24 fps: the prediction resampled from 30 fps; the ground truth's last "
        "frame (1.250 s) is past the prediction's end (1.233 s): not scored"
    )
    a, b, note = common_rate(guess, truth)  # the other way round
    assert note.endswith("the prediction's last frame (1.250 s) is past the ground truth's end "
                         "(1.233 s): not scored")  # fmt: skip
    even = motion_from_arrays(motion_arrays(T=31, fps=30.0))
    _, _, note = common_rate(motion_from_arrays(motion_arrays(T=121, fps=120.0)), even)
    assert note == "evaluated at 30 fps: the ground truth resampled from 120 fps"


@needs_cmu
def test_amc_at_a_given_rate_is_not_said_to_hold_another(tmp_path):
    """An AMC file holds no frame rate: imported with --source-fps 60 it was noted "frame rate
    120 in the file, 60 used" and its record said source_fps 120."""
    import json

    lines = gzip.open(CMU / "asfamc/07/07_01.amc.gz", "rt").read().splitlines()
    take = tmp_path / "07_01.amc"
    take.write_text("\n".join(lines[: 3 + 30 * 30]) + "\n")  # 30 frames of 30 lines
    code, out, err = run("import", take, "--asf", CMU / "asfamc/07/07.asf", "-o",
                         tmp_path / "at60.npz", "--source-fps", "60", "--fps", "0")  # fmt: skip
    assert code == 0, err
    assert "in the file" not in out + err
    made = np.load(tmp_path / "at60.npz")
    record = json.loads(str(made["source"]))
    assert made["poses"].shape[0] == 30 and float(made["mocap_framerate"]) == 60.0
    assert record["source_fps"] == 60.0 and record["notes"] == []


@needs_cmu
def test_a_take_beside_several_skeletons_is_told_so(tmp_path):
    """walk.amc in a folder with a.asf and b.asf: the message said no .asf was next to it."""
    lines = gzip.open(CMU / "asfamc/07/07_01.amc.gz", "rt").read().splitlines()
    (tmp_path / "walk.amc").write_text("\n".join(lines[: 3 + 10 * 30]) + "\n")
    for name in ("a.asf", "b.asf"):
        (tmp_path / name).write_bytes((CMU / "asfamc/07/07.asf").read_bytes())
    code, out, err = run("import", tmp_path / "walk.amc", "-o", tmp_path / "walk.npz")
    assert code == 1 and not (tmp_path / "walk.npz").exists()
    assert f"error: {tmp_path / 'walk.amc'}: 2 .asf skeletons next to it (a.asf, b.asf), none " \
           "named for it; pass --asf FILE" in out + err  # fmt: skip


@needs_cmu
def test_denoise_says_when_the_output_folder_holds_another_skeleton(tmp_path):
    """A cleaned AMC written where a different 07.asf already lies: that file is kept, and
    the output (which would read on the wrong skeleton) is said, not left silent."""
    lines = gzip.open(CMU / "asfamc/07/07_01.amc.gz", "rt").read().splitlines()
    takes, out = tmp_path / "takes", tmp_path / "out"
    takes.mkdir(), out.mkdir()
    (takes / "07_01.amc").write_text("\n".join(lines[: 3 + 40 * 30]) + "\n")
    (takes / "07.asf").write_bytes((CMU / "asfamc/07/07.asf").read_bytes())
    other = (CMU / "asfamc/07/07.asf").read_bytes().replace(b"length 0.45", b"length 0.5")
    (out / "07.asf").write_bytes(other)
    code, stdout, err = run("denoise", takes / "07_01.amc", "-o", out / "07_01.amc")
    assert code == 0, err
    assert (out / "07.asf").read_bytes() == other and (out / "07_01.amc").is_file()
    said = " ".join((stdout + err).split())
    assert f"{out / '07.asf'} is not the take's skeleton {takes / '07.asf'}: left as it is" in said
    (out / "07.asf").unlink()  # none there: the take's own copied, nothing said
    code, stdout, err = run("denoise", takes / "07_01.amc", "-o", out / "07_01.amc")
    assert code == 0 and "skeleton" not in stdout + err
    assert (out / "07.asf").read_bytes() == (takes / "07.asf").read_bytes()


SMALL_ASF = """:version 1.10
:units
  mass 1.0
  length 0.45
  angle rad
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name b1
     direction 1 0 0
     length 10
     axis 0 0 1.5707963 XYZ
    dof rx
    limits (-3.14 3.14)
  end
:hierarchy
  begin
    root b1
  end
"""


def test_asf_units_on_one_line_and_fields_without_values():
    """``:units mass 1.0 length 0.45 angle rad`` on one line was read as no length and
    degrees; a field without its value (``angle``, the root's ``axis``, a bone's ``name``)
    was an IndexError, said as "list index out of range" against the AMC."""
    from mdvae_cli.errors import InputError
    from mdvae_cli.formats.asf import parse_asf

    per_line = parse_asf(SMALL_ASF)
    one_line = parse_asf(SMALL_ASF.replace("\n  mass 1.0\n  length 0.45\n  angle rad",
                                           " mass 1.0 length 0.45 angle rad"))  # fmt: skip
    assert (per_line.length_unit, per_line.degrees) == (0.45, False)
    assert (one_line.length_unit, one_line.degrees) == (0.45, False)
    for old, new, said in (("angle rad", "angle", ":units angle has no value"),
                           ("axis XYZ", "axis", "the root's axis has no value"),
                           ("name b1", "name", "a bone block has no name")):  # fmt: skip
        with pytest.raises(InputError, match=f"^x.asf: {said}$"):
            parse_asf(SMALL_ASF.replace(old, new), "x.asf")


def test_a_take_that_stands_then_lies_down_is_not_said_to_lie(tmp_path):
    """HDM05's depositFloorR and lieDownFloor takes (20 of 234) stand for 22-48 % of their
    frames and bend to or lie on the floor the rest: the importer said "the body is upright
    along -x ... kept as it lies" of a person standing up in its own axes. Kept as it lies
    (the output unchanged), with no note; a take lying throughout keeps its note."""
    import json

    import numpy as np

    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.formats.npz_io import load_motion
    from mdvae_cli.motion.motion import slice_frames
    from mdvae_cli.retarget.fit_shape import BodyJoints
    from mdvae_cli.retarget.retarget import RetargetSettings, import_motion, load_source
    from mdvae_cli.retarget.smpl_bvh import smpl_bvh
    from tests.test_bvh_axes_rates import turned

    joints = BodyJoints(load_body_model(None))
    walk = slice_frames(load_motion(REPO / "examples" / "walk.npz"), 0, 60)
    Rx = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +90 degrees about x: lying
    lying = turned(walk, joints, Rx, np.asarray(walk.trans).mean(0))
    notes = {}
    for standing in (0, 12):  # frames upright first: none, a fifth of the take
        take = lying.with_body(
            root_orient=np.concatenate([walk.root_orient[:standing], lying.root_orient[standing:]]),
            trans=np.concatenate([walk.trans[:standing], lying.trans[standing:]]),
        )
        path = tmp_path / f"take{standing}.bvh"
        path.write_text(smpl_bvh(take, joints))
        rt = import_motion(load_source(path), joints, fps=None,
                           settings=RetargetSettings(floor="none"))  # fmt: skip
        notes[standing] = json.loads(str(rt.motion.extras["source"]))["notes"]
    assert any("kept as it lies" in n for n in notes[0])
    assert not any("upright along" in n for n in notes[12])


@needs_cmu
def test_amc_numbered_every_second_frame_is_a_take_at_half_the_rate(tmp_path):
    """A 60-frame take exported every 2nd frame of a 120 Hz capture (numbered 1, 3, 5, ...)
    was read as 59 one-frame holes: 119 frames at 120 fps, half of them made up, and denoise
    wrote back 119 frames. Now 60 consecutive frames at 60 fps (the same timing), written
    back with their own numbers; one irregular gap stays a hole."""
    lines = gzip.open(CMU / "asfamc/07/07_01.amc.gz", "rt").read().splitlines()
    asf = CMU / "asfamc/07/07.asf"
    head, body = lines[:3], lines[3 : 3 + 60 * 30]
    renumber = {str(k + 1): str(2 * k + 1) for k in range(60)}
    odd = tmp_path / "07_01.amc"
    odd.write_text("\n".join(head + [renumber.get(ln, ln) for ln in body]) + "\n")
    code, out, err = run("import", odd, "--asf", asf, "-o", tmp_path / "odd.npz", "--fps", "0")
    assert code == 0, err
    made = np.load(tmp_path / "odd.npz")
    assert made["poses"].shape[0] == 60 and float(made["mocap_framerate"]) == 60.0
    assert "joint_mask" not in made.files
    assert "frame numbers step by 2 throughout (1, 3, 5, ...)" in " ".join((out + err).split())
    code, _, err = run("denoise", odd, "--asf", asf, "-o", tmp_path / "clean.amc")
    assert code == 0, err
    numbers = [ln for ln in (tmp_path / "clean.amc").read_text().splitlines() if ln.isdigit()]
    assert numbers == [str(2 * k + 1) for k in range(60)]

    from mdvae_cli.formats.amc_frames import even_step

    assert [even_step(n) for n in ([1, 3, 5], [1, 3], [1, 3, 5, 8], [0, 1, 2], [4, 8, 12])] == [
        2, 1, 1, 1, 4]  # fmt: skip
