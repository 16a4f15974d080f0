"""``--fps`` in every command that reads motion: a BVH whose Frame Time holds a rate."""

from __future__ import annotations

import json

from tests.conftest import run_cli as run
from tests.test_bvh_out import write_rig


def test_a_frame_time_that_is_a_rate_is_given_by_fps_in_every_command(tmp_path):
    good = write_rig(tmp_path / "good.bvh", T=40, fps=30.0)
    text = good.read_text()
    rate = tmp_path / "rate.bvh"
    rate.write_text(text.replace(next(ln for ln in text.splitlines() if "Frame Time" in ln),
                                 "Frame Time: 30"))  # fmt: skip

    code, out, err = run("denoise", rate, "-o", tmp_path / "x.bvh")
    assert code == 1 and "is its Frame Time a frame rate? (1/0.0333333 = 30 Hz)" in err
    assert "give the rate with --fps" in err and "Traceback" not in err

    code, out, err = run("view", rate, "-o", tmp_path / "x.html", "--fps", 30, "--json")
    assert code == 0, err
    (motion,) = json.loads(out)["motions"]
    assert motion["frames"] == 40 and motion["fps"] == 30
    code, out, err = run("eval", "--gt", good, "--pred", rate, "--fps", 30, "--json")
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert result["num_frames"] == 40 and result["v2v_cm"] < 1e-6
    code, out, err = run("plot", rate, "-o", tmp_path / "x.png", "--fps", 30)
    assert code == 0, err


def _as_rate_line(text: str, rate: str) -> str:
    """A BVH's text with its Frame Time replaced by ``rate`` (a rate where a period belongs)."""
    line = next(ln for ln in text.splitlines() if "Frame Time" in ln)
    return text.replace(line, f"Frame Time: {rate}")


def test_eval_sets_the_rate_of_one_side_with_gt_fps_or_pred_fps(tmp_path):
    """A 120 Hz ground truth (4 s) against the same motion kept every 4th frame (30 Hz), both
    with a rate where the Frame Time belongs: --fps sets both sides, so only the side options
    score it, at 30 Hz on the 120 frames the prediction has, with no error."""
    hi = write_rig(tmp_path / "hi.bvh", T=480, fps=120.0).read_text()
    head, motion = hi.split("MOTION\n")
    rows = motion.splitlines()[2:]
    lo = f"{head}MOTION\nFrames: 120\nFrame Time: 30\n" + "\n".join(rows[::4]) + "\n"
    (tmp_path / "gt.bvh").write_text(_as_rate_line(hi, "120"))
    (tmp_path / "pred.bvh").write_text(lo)
    gt, pred = tmp_path / "gt.bvh", tmp_path / "pred.bvh"

    code, out, err = run("eval", "--gt", gt, "--pred", pred, "--fps", 30, "--json")
    assert code == 1 and "lengths differ: ground truth 480 frames, prediction 120 frames" in err
    code, out, err = run("eval", "--gt", gt, "--pred", pred, "--gt-fps", 120,
                         "--pred-fps", 30, "--json")  # fmt: skip
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert result["num_frames"] == 120 and result["v2v_cm"] < 1e-3
    assert "the ground truth resampled from 120 fps" in err
    # --fps is both sides unless one is named: --fps 30 with --gt-fps 120 is the same
    code, out2, err = run("eval", "--gt", gt, "--pred", pred, "--fps", 30, "--gt-fps", 120,
                          "--json")  # fmt: skip
    assert code == 0 and json.loads(out2)["files"][0]["result"] == result
    code, out, err = run("eval", "--gt", gt, "--pred", pred, "--pred-fps", 0)
    assert code != 0 and "Traceback" not in err
