"""``mdvae plot``: the before/after figure drawn with matplotlib (the ``[plot]`` extra), and
the one-line error where matplotlib is missing."""

from __future__ import annotations

import io
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.view.figure import (
    DPI,
    INSTALL,
    PALETTE,
    FigureSpec,
    draw_figure,
    figure_bytes,
    figure_size,
    joint_index,
)
from tests.conftest import motion_arrays


@pytest.fixture
def mpl():
    """matplotlib, the ``[plot]`` extra (in ``[test]`` too): tests that draw need it."""
    return pytest.importorskip("matplotlib")


def pixels(png: bytes) -> np.ndarray:
    """(H, W, 3) floats in [0, 1]."""
    from matplotlib.image import imread

    return imread(io.BytesIO(png), format="png")[..., :3]


def share_of(img: np.ndarray, color: str, tol: float = 0.02) -> float:
    """The share of pixels drawn in ``color`` (within ``tol`` per channel)."""
    from matplotlib.colors import to_rgb

    return float((np.abs(img - np.array(to_rgb(color))) < tol).all(-1).mean())


def items(n: int = 2, T: int = 40):
    return [
        (f"m{i}.npz", motion_from_arrays(motion_arrays(T=T + 20 * i, seed=i))) for i in range(n)
    ]


def test_helpers():
    assert joint_index("left knee") == 4 == joint_index("4") == joint_index("Left_Knee")
    with pytest.raises(InputError, match="unknown joint"):
        joint_index("tail")
    for bad in (FigureSpec(series="x"), FigureSpec(joints=(22,)), FigureSpec(frames=0),
                FigureSpec(width=100)):  # fmt: skip
        with pytest.raises(InputError):
            bad.validate()


def test_figure_draws_every_motion_in_its_colour_at_the_width_asked(tiny_body, mpl):
    body = BodyModel(tiny_body)
    spec = FigureSpec(joints=(4, 15), frames=4, width=800)  # the head has no bend: still drawn
    figure = draw_figure(items(3), body, spec)
    img = pixels(figure_bytes(figure, "png"))
    assert img.shape[:2] == figure_size(figure)[::-1] and img.shape[1] == 800
    for color in PALETTE[:3]:
        assert share_of(img, color) > 0.002, color  # curves, contact bars, skeletons
    assert share_of(img, PALETTE[3]) == 0  # no fourth motion
    assert share_of(img, "#ffffff") > 0.5  # a white page
    taller = draw_figure(items(3), body, FigureSpec(joints=(4, 5, 15), frames=4, width=800))
    assert figure_size(taller)[1] > figure_size(figure)[1]  # a panel more: taller


def test_the_pixels_follow_the_takes_and_nothing_else(tiny_body, mpl):
    body, spec = BodyModel(tiny_body), FigureSpec(frames=3, width=600)
    a, b = items(2)
    png = [figure_bytes(draw_figure([m], body, spec), "png") for m in (a, a, b)]
    assert png[0] == png[1]  # the same take: the same file, byte for byte
    one, other = pixels(png[0]), pixels(png[2])
    assert one.shape == other.shape  # same layout ...
    assert np.abs(one - other).max() > 0.5 and (np.abs(one - other) > 0.1).any(-1).mean() > 0.01


def test_svg_is_the_same_figure_as_vector(tiny_body, mpl):
    figure = draw_figure(items(2), BodyModel(tiny_body), FigureSpec(frames=2, width=1000))
    root = ET.fromstring(figure_bytes(figure, "svg"))
    assert root.attrib["width"] == f"{1000 / DPI * 72:g}pt"  # 72 points an inch
    drawn = ET.tostring(root).decode()
    assert all(c in drawn for c in PALETTE[:2]) and "m1.npz" in drawn


def test_plot_command_png_and_svg(tmp_path, make_motion_file, mpl):
    a = make_motion_file("noisy.npz", T=50)
    b = make_motion_file("clean.npz", T=50, seed=1)
    for name in ("fig.png", "fig.svg"):
        out = tmp_path / name
        args = ["plot", str(a), str(b), "-o", str(out), "--joint", "left_hip", "--frames", "3"]
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, result.output
        data = out.read_bytes()
        if name.endswith("png"):
            assert pixels(data).shape[1] == 1400
        else:
            assert ET.fromstring(data).attrib["width"] == f"{1400 / DPI * 72:g}pt"
    for args, message in (
        (["-o", str(tmp_path / "f.jpg")], "must end in"),
        (["-o", str(tmp_path / "f.png"), "--joint", "tail"], "unknown joint"),
    ):
        result = CliRunner().invoke(cli, ["plot", str(a), *args])
        assert result.exit_code == 1 and message in result.output
        assert result.output.startswith("error:")


def test_without_matplotlib_plot_says_how_to_install_it(tmp_path, make_motion_file, monkeypatch):
    a = make_motion_file("a.npz", T=40)
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    out = tmp_path / "f.png"
    result = CliRunner().invoke(cli, ["plot", str(a), "-o", str(out)])
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 1 and lines == [f"error: {INSTALL}"]
    assert not out.exists()
