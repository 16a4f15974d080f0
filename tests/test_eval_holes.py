"""``mdvae eval`` on files with holes: frames missing in either file are not scored."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import run_cli as run
from tests.test_cli_basic import small_default_body  # noqa: F401 (fixture)


def test_eval_leaves_out_the_frames_a_file_does_not_have(
    small_default_body,  # noqa: F811
    make_motion_file,
    tmp_path,
):
    clean = make_motion_file("clean.npz", T=40, fps=30.0)
    arrays = dict(np.load(clean))
    poses = arrays["poses"].copy()
    poses[10:25] = np.nan  # 15 frames the ground truth lacks
    holes = make_motion_file("holes.npz", T=40, fps=30.0, poses=poses)

    for gt, pred in ((holes, clean), (clean, holes)):
        code, out, err = run("eval", "--gt", gt, "--pred", pred, "--json")
        assert code == 0, err
        result = json.loads(out)["files"][0]["result"]
        # the prediction equals the ground truth on every frame both have
        assert result["v2v_cm"] == pytest.approx(0.0, abs=1e-9)
        assert (result["num_frames"], result["unscored_frames"]) == (25, 15)
        assert result["accel_count"] == 8 + 13  # inner frames 1-8 and 26-38
        assert "15 of 40 frames missing" in err and "not scored" in err
