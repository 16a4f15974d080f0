"""``mdvae export-mesh --frames START:STOP``: a shot's frames only, files named by the source
frame; a range that is not one, or that holds no frame of a take, refused in one line."""

from __future__ import annotations

import pytest

from mdvae_cli.errors import InputError
from mdvae_cli.export import frame_span
from tests.conftest import one_error_line, run_cli


@pytest.mark.parametrize(("text", "span"), [("120:240", (120, 240)), ("120:", (120, None)),
                                            (":90", (0, 90)), (" 3 : 7 ", (3, 7))])  # fmt: skip
def test_frame_span_reads_start_and_stop(text, span):
    assert frame_span(text) == span


@pytest.mark.parametrize("text", ["5", "a:b", "-3:5", "10:10", "20:10", "", "1:2:3"])
def test_frame_span_refuses_what_is_not_a_range(text):
    with pytest.raises(InputError, match="--frames"):
        frame_span(text)


def test_export_mesh_writes_the_frames_asked_for(tmp_path, make_motion_file):
    take = make_motion_file("take.npz", T=30)
    out = tmp_path / "meshes"
    code, _, err = run_cli("export-mesh", take, "-o", out, "--frames", "10:20", "--every", "3")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [
        "frame_000010.ply", "frame_000013.ply", "frame_000016.ply", "frame_000019.ply"]  # fmt: skip
    code, _, err = run_cli("export-mesh", take, "-o", out, "--frames", "28:500")  # to the end
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["frame_000028.ply", "frame_000029.ply"]


def test_a_bad_range_is_one_line_and_writes_nothing(tmp_path, make_motion_file):
    take = make_motion_file("take.npz", T=30)
    out = tmp_path / "meshes"
    line = one_error_line(*run_cli("export-mesh", take, "-o", out, "--frames", "20:10"))
    assert "START must be 0 or more and STOP after it" in line
    line = one_error_line(*run_cli("export-mesh", take, "-o", out, "--frames", "30:"))
    assert line == f"error: {take}: --frames 30: holds no frame of this take (frames 0 to 29)"
    assert not out.exists()
