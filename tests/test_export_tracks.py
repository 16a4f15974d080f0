"""``export-bvh`` and ``export-mesh`` read files as the other commands do: a file of several
people (WHAM) with ``--track ID``, an AMC whose skeleton is elsewhere with ``--asf``, a video
result's rate with ``--fps`` (their refusals named options they did not have)."""

from __future__ import annotations

from tests import video_files as vf
from tests.conftest import one_error_line, run_cli


def wham_file(tmp_path):
    tracks = {0: (vf.clip(T=40, seed=0), None), 3: (vf.clip(T=30, seed=1), None)}
    return vf.write_wham(tmp_path / "wham_output.pkl", tracks)


def test_export_bvh_takes_the_track_named(tmp_path):
    wham = wham_file(tmp_path)
    line = one_error_line(*run_cli("export-bvh", wham, "-o", tmp_path / "a.bvh"))
    assert "holds 2 tracks (0, 3); pick one with --track ID" in line
    code, _, err = run_cli("export-bvh", wham, "-o", tmp_path / "t3.bvh", "--track", "3")
    assert code == 0, err
    assert "Frames: 30\n" in (tmp_path / "t3.bvh").read_text()
    line = one_error_line(*run_cli("export-bvh", wham, "-o", tmp_path / "b.bvh", "--track", "7"))
    assert "no track '7' (tracks: 0, 3)" in line


def test_export_mesh_takes_the_track_named(tmp_path):
    wham = wham_file(tmp_path)
    out = tmp_path / "meshes"
    code, _, err = run_cli("export-mesh", wham, "-o", out, "--track", "0", "--every", "20")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["frame_000000.ply", "frame_000020.ply"]


def test_exports_read_takes_as_the_other_commands_do(tmp_path):
    """An AMC whose skeleton is elsewhere (--asf, which the refusal names) and a video
    result at its own rate (--fps, which it does not store): both were refused or written at
    30 Hz, the options missing."""
    from tests.test_amc_out import write_take_files

    amc, asf = write_take_files(tmp_path / "skeleton", T=24)
    take = tmp_path / "takes" / amc.name
    take.parent.mkdir()
    amc.rename(take)
    line = one_error_line(*run_cli("export-bvh", take, "-o", tmp_path / "a.bvh"))
    assert "pass --asf FILE" in line
    code, _, err = run_cli("export-bvh", take, "-o", tmp_path / "a.bvh", "--asf", asf)
    assert code == 0, err
    assert "Frames: 24\n" in (tmp_path / "a.bvh").read_text()
    code, _, err = run_cli("export-mesh", take, "-o", tmp_path / "m", "--asf", asf,
                           "--frames", "0:2")  # fmt: skip
    assert code == 0, err
    assert len(list((tmp_path / "m").iterdir())) == 2
    wham = wham_file(tmp_path)
    code, _, err = run_cli("export-bvh", wham, "-o", tmp_path / "w.bvh", "--track", "3",
                           "--fps", "25")  # fmt: skip
    assert code == 0, err
    assert "Frame Time: 0.04\n" in (tmp_path / "w.bvh").read_text()
