"""Output paths that look like console markup (``[bold]``, ``[/red]``) are printed as they are
by ``mdvae view``, ``plot``, ``export-bvh``, ``export-mesh``, ``add-noise`` and ``sample``:
never read as styles (a wrong name on screen) nor refused after the file was written (a
closing tag that opens nothing)."""

from __future__ import annotations

import pytest

from tests.conftest import run_cli

NAMES = ["[/red]take", "[bold]take[red]"]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize(
    "command, suffix, extra",
    [("view", ".html", ["--no-mesh"]), ("export-bvh", ".bvh", []),
     ("export-mesh", "", ["--every", "20"]), ("add-noise", ".npz", ["--sigma", "0.1"]),
     ("sample", ".npz", ["--frames", "8", "--from"])],
)  # fmt: skip
def test_the_written_path_is_printed_as_it_is(tmp_path, make_motion_file, command, suffix,
                                               extra, name):  # fmt: skip
    source = make_motion_file("in.npz", T=30)
    out = tmp_path / f"{name}{suffix}"
    args = [source, "-o", out, *extra] if command != "sample" else ["-o", out, *extra, source]
    code, stdout, stderr = run_cli(command, *args)
    assert code == 0, stdout + stderr
    assert out.exists()
    said = stderr.replace("\n", "")  # the console wraps long lines
    assert str(out) in said and "MarkupError" not in said


def test_plot_prints_its_path_as_it_is(tmp_path, make_motion_file):
    pytest.importorskip("matplotlib")
    source = make_motion_file("in.npz", T=30)
    out = tmp_path / "[/red]fig.png"
    code, stdout, stderr = run_cli("plot", source, "-o", out, "--frames", "2", "--width", "400")
    assert code == 0, stdout + stderr
    assert out.exists() and f"wrote {out} (" in stderr.replace("\n", "")
