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
