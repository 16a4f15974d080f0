"""``mdvae eval`` on two folders: a cleaned folder names its files its own way (walk_clean.npz
for walk.npz, a BVH take cleaned into an npz); files are paired by path, then by name where
one file fits, each pair so made said, ambiguity refused for that file in one line."""

from __future__ import annotations

import json
from pathlib import PurePath as P

import pytest

from mdvae_cli.cli.eval_pairs import name_fits, pair_by_name
from tests.conftest import run_cli as run


@pytest.fixture
def small_default_body(monkeypatch, tiny_body):
    from mdvae_cli.cli import eval_cmd

    real = eval_cmd.load_body_model
    monkeypatch.setattr(eval_cmd, "load_body_model",
                        lambda path: tiny_body if path is None else real(path))  # fmt: skip


def test_a_name_fits_itself_or_itself_with_a_word_added():
    assert name_fits("walk", "walk") and name_fits("walk", "walk_clean")
    assert name_fits("walk", "clean-walk") and name_fits("walk", "walk.denoised")
    assert not name_fits("walk", "walking") and not name_fits("walk", "sidewalk")
    assert not name_fits("walk", "wal") and not name_fits("01_01", "01_011")


def test_pairs_by_name_take_the_longest_name_and_refuse_what_is_ambiguous():
    gts = [P("walk.npz"), P("walk_fast.npz"), P("run.bvh"), P("jump.npz"), P("a/hop.npz"),
           P("b/spin.bvh"), P("b/spin.npz")]  # fmt: skip
    preds = [P("walk_clean.npz"), P("walk_fast_clean.npz"), P("run.npz"), P("jump_1.npz"),
             P("jump_2.npz"), P("hop_clean.npz"), P("b/spin_clean.npz"),
             P("extra.npz")]  # fmt: skip
    pairs, clashes, unfit = pair_by_name(gts, preds)
    assert pairs == {P("walk.npz"): P("walk_clean.npz"),
                     P("walk_fast.npz"): P("walk_fast_clean.npz"),
                     P("run.bvh"): P("run.npz")}  # fmt: skip
    assert clashes == {
        P("jump.npz"): "jump_1.npz, jump_2.npz fit its name alike: rename or move all but one",
        P("b/spin.bvh"): "spin_clean.npz fits spin.bvh and spin.npz alike: rename it",
        P("b/spin.npz"): "spin_clean.npz fits spin.bvh and spin.npz alike: rename it",
    }
    assert unfit == [P("hop_clean.npz"), P("extra.npz")]  # another folder: no partner


def test_eval_pairs_a_cleaned_folder_by_name_and_says_so(
    small_default_body, make_motion_file, tmp_path
):
    # before: every file here failed with "no prediction", each prediction "has no ground truth"
    for name in ("walk", "jump", "alone"):
        make_motion_file(f"gt/{name}.npz", T=6, seed=1)
    make_motion_file("pred/walk_clean.npz", T=6, seed=2)
    make_motion_file("pred/jump_a.npz", T=6, seed=2)
    make_motion_file("pred/jump_b.npz", T=6, seed=2)
    make_motion_file("pred/extra.npz", T=6, seed=2)
    code, out, err = run("eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred", "--json")
    assert code == 1  # two files without a partner
    data = json.loads(out)
    rows = {f["file"]: f for f in data["files"]}
    assert rows["walk.npz"]["ok"] and rows["walk.npz"]["pred"] == str(
        tmp_path / "pred/walk_clean.npz"
    )
    assert rows["walk.npz"]["result"]["v2v_cm"] > 0
    assert rows["jump.npz"]["pred"] is None and rows["jump.npz"]["error"] == (
        f"{tmp_path / 'gt/jump.npz'}: no prediction paired: jump_a.npz, jump_b.npz fit its "
        "name alike: rename or move all but one"
    )
    assert "alone.npz, nor one named alone.* or alone_*.* beside it" in rows["alone.npz"]["error"]
    assert data["unpaired_predictions"] == [str(tmp_path / "pred/extra.npz")]
    assert "note: walk.npz: paired with walk_clean.npz by name" in err
    assert f"note: {tmp_path / 'pred/extra.npz'} has no ground truth; skipped\n" in err
    assert err.count("error: ") == 2


def test_a_prediction_folder_inside_the_ground_truths_is_not_read_as_ground_truth(
    small_default_body, make_motion_file, tmp_path
):
    # `mdvae add-noise takes/ -o takes/noisy/` then `mdvae eval --gt takes --pred takes/noisy`:
    # before, takes/noisy/walk.npz was also a ground truth, failing with "no prediction"
    make_motion_file("takes/walk.npz", T=6, seed=1)
    make_motion_file("takes/noisy/walk.npz", T=6, seed=2)
    code, out, err = run("eval", "--gt", tmp_path / "takes", "--pred", tmp_path / "takes/noisy",
                         "--json")  # fmt: skip
    assert code == 0, err
    data = json.loads(out)
    assert [f["file"] for f in data["files"]] == ["walk.npz"] and data["failed"] == 0
    code, out, err = run("eval", "--gt", tmp_path / "takes/noisy", "--pred", tmp_path / "takes",
                         "--json")  # fmt: skip
    assert code == 0 and json.loads(out)["unpaired_predictions"] == []
