"""``mdvae denoise`` options that do nothing beside the others given are refused in one line
(before, each was dropped without a word: ``--refine 10 --no-offset`` wrote the very bytes of
``--refine 10``, ``--blend --no-offset`` those of ``--no-offset``), and ``--loop`` on a take
whose ends do not meet says so."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.npz_io import load_motion, save_motion

NOISY = Path(__file__).resolve().parent.parent / "examples" / "noisy_walk.npz"
NOT_A_LOOP = "not a loop"


def invoke(*args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception
    return res


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--refine", "3", "--no-offset"], "--refine already fits the offset; drop --no-offset"),
        (["--no-offset", "--blend"], "--blend goes with the offset or --refine"),
        (["--no-offset", "--guard"], "--guard goes with the offset or --refine"),
        (["--no-offset", "--refine-offset", "0.1"], "--refine-offset goes with the offset"),
        (["--no-offset", "--trans-offset", "0.1"], "--trans-offset goes with the offset"),
        (["--refine", "3", "--trans-offset", "0.1"], "--refine fits the translation itself"),
        (["--refine-lr", "0.2"], "--refine-lr only applies with --refine N"),
        (["--seed", "3"], "--seed only applies with --optimize N"),
    ],
)
def test_options_that_would_do_nothing_are_refused_in_one_line(tmp_path, extra, message):
    out = tmp_path / "o.npz"
    res = invoke("denoise", NOISY, "-o", out, *extra)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 1 and len(lines) == 1 and lines[0].startswith("error: "), lines
    assert message in lines[0] and not out.exists()
    res = invoke("denoise", NOISY, "-o", out, *extra, "--json")  # --json: refused as JSON
    assert res.exit_code == 1 and json.loads(res.stdout)["ok"] is False and not out.exists()


@pytest.mark.parametrize(
    "extra",
    [
        ["--no-offset", "--no-blend", "--no-guard"],  # saying the mode's own choices is fine
        ["--refine", "1", "--refine-lr", "0.2", "--refine-offset", "0"],
        ["--optimize", "1", "--seed", "3"],
    ],
)
def test_options_that_apply_still_run(tmp_path, extra):
    res = invoke("denoise", NOISY, "-o", tmp_path / "o.npz", *extra)
    assert res.exit_code == 0, res.output
    assert load_motion(tmp_path / "o.npz").num_frames == 79


def _cycle(frames: int = 80, period: int = 40):
    """The example walk's first pose swinging its joints by 0.2 rad on a ``period``-frame
    sine, standing on the spot: a take whose last frame leads into its first."""
    walk = load_motion(NOISY.with_name("walk.npz"))
    phase = np.sin(2 * np.pi * np.arange(frames) / period)[:, None, None]
    pose = walk.pose_body[:1] + 0.2 * phase
    return replace(
        walk,
        root_orient=np.repeat(walk.root_orient[:1], frames, 0),
        pose_body=pose.astype(walk.pose_body.dtype),
        trans=np.repeat(walk.trans[:1], frames, 0),
        pose_extra=None if walk.pose_extra is None else np.repeat(walk.pose_extra[:1], frames, 0),
    )


def test_loop_on_a_take_that_is_not_one_says_so(tmp_path):
    out = tmp_path / "o.npz"
    res = invoke("denoise", NOISY, "-o", out, "--loop", "--json")  # a walk 3.5 m long
    assert res.exit_code == 0, res.output
    (row,) = json.loads(res.stdout)["files"]
    assert row["result"]["loop"] is True
    assert sum(NOT_A_LOOP in n for n in row["result"]["notes"]) == 1
    res = invoke("denoise", NOISY, "-o", out)  # detection says nothing of it
    assert res.exit_code == 0 and NOT_A_LOOP not in res.output and "loop" not in res.output
    cycle = tmp_path / "cycle.npz"
    save_motion(_cycle(), cycle)
    res = invoke("denoise", cycle, "-o", tmp_path / "c.npz", "--loop")
    assert res.exit_code == 0 and NOT_A_LOOP not in res.output, res.output


def test_json_says_where_the_page_and_meshes_went(tmp_path):
    """Before, --json named only the output: the page and the meshes were not in it."""
    out, pages, meshes = tmp_path / "o.npz", tmp_path / "pages", tmp_path / "meshes"
    res = invoke("denoise", NOISY, "-o", out, "--view", pages, "--mesh-dir", meshes, "--json")
    assert res.exit_code == 0, res.output
    (track,) = json.loads(res.stdout)["files"][0]["result"]["tracks"]
    assert track["page"] == str(pages / "noisy_walk.html") and Path(track["page"]).is_file()
    assert track["meshes"] == str(meshes) and len(list(meshes.glob("*.ply"))) == 79
    res = invoke("denoise", NOISY, "-o", out, "--json")  # none asked: no such keys
    (track,) = json.loads(res.stdout)["files"][0]["result"]["tracks"]
    assert "page" not in track and "meshes" not in track


def test_asf_and_joint_map_with_no_take_among_the_inputs_are_noted(tmp_path):
    """Before, --asf and --joint-map beside npz inputs alone were dropped without a word."""
    asf, jmap = tmp_path / "07.asf", tmp_path / "map.json"
    asf.write_text(":version 1.10\n")  # never read: no AMC take asks for it
    jmap.write_text('{"pelvis": "Hips"}')
    res = invoke("denoise", NOISY, "-o", tmp_path / "o.npz", "--asf", asf, "--joint-map", jmap)
    assert res.exit_code == 0, res.output
    assert "note: --asf applies to AMC takes, and no input is one; ignored" in res.output
    assert "note: --joint-map applies to BVH/AMC takes, and no input is one; ignored" in res.output
    res = invoke("denoise", NOISY, "-o", tmp_path / "p.npz")
    assert res.exit_code == 0 and "--asf" not in res.output and "--joint-map" not in res.output


def test_a_torch_file_is_written_as_the_same_bytes_every_time(tmp_path):
    """A GVHMR .pt written back: the same result twice is the same bytes (before, the
    archive's folder inside the zip was named after the random temporary file)."""
    import torch

    from mdvae_cli.formats.data_write import write_data

    obj = {"smpl_params_global": {"body_pose": np.arange(12, dtype=np.float32).reshape(2, 6)}}
    first, second = tmp_path / "a.pt", tmp_path / "b" / "a.pt"
    second.parent.mkdir()
    write_data(obj, first, "torch")
    write_data(obj, second, "torch")
    assert first.read_bytes() == second.read_bytes()
    back = torch.load(first, weights_only=True)["smpl_params_global"]["body_pose"]
    assert torch.equal(back, torch.arange(12, dtype=torch.float32).reshape(2, 6))
