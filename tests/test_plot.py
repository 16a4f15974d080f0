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


def test_frames_missing_in_the_file_are_shaded_and_counted(mpl, tiny_body):
    """Frames 20-29 of a take lost a joint (NaN in the file; the reader's placeholders stand
    in): each curve panel shades them in the take's colour and the legend counts them, as the
    page does (before: the placeholders were drawn as if they were the file's data)."""
    from matplotlib.colors import to_rgba

    holes = motion_from_arrays(motion_arrays(T=60, seed=1))
    holes.joint_mask = np.ones((60, 22), bool)
    holes.joint_mask[20:30, 16] = False
    plain = motion_from_arrays(motion_arrays(T=60, seed=2))
    fig = draw_figure([("holes", holes), ("plain", plain)], BodyModel(tiny_body),
                      FigureSpec(joints=(4, 5), frames=2, width=600))  # fmt: skip
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert texts == ["holes (60 frames, 30 Hz, 10 filled (shaded))", "plain (60 frames, 30 Hz)"]
    for ax in fig.axes[:2]:  # the two curve panels
        spans = [p for p in ax.patches if p.get_facecolor()[:3] == to_rgba(PALETTE[0])[:3]]
        assert len(spans) == 2  # the shade and the bar along the top
        for p in spans:
            x0 = p.get_x() if hasattr(p, "get_x") else p.get_xy()[:, 0].min()
            w = p.get_width() if hasattr(p, "get_width") else np.ptp(p.get_xy()[:, 0])
            assert abs(x0 - 19.5 / 30) < 1e-9 and abs(w - 10 / 30) < 1e-9
        assert not [p for p in ax.patches if p.get_facecolor()[:3] == to_rgba(PALETTE[1])[:3]]


def test_filmstrip_draws_each_body_in_its_own_cell_wherever_it_is(mpl, tiny_body):
    """Two takes 11.7 m apart: each row's bodies stand in their own cells, the pelvis at the
    middle (before: both about the point between them, 5.8 m out of their cells)."""
    near = motion_from_arrays(motion_arrays(T=40, seed=0))
    far = near.with_body(trans=near.trans + np.array([10.0, 6.0, 0.0]))
    fig = draw_figure([("near", near), ("far", far)], BodyModel(tiny_body),
                      FigureSpec(joints=(4,), frames=3, width=600))  # fmt: skip
    for ax in fig.axes[-2:]:  # the filmstrip's rows
        width = ax.get_xlim()[1] / 3
        xs = np.concatenate([line.get_xdata() for line in ax.lines])
        assert xs.min() >= 0 and xs.max() <= 3 * width
        starts = {round(float(line.get_xdata()[0]), 9) for line in ax.lines}
        for k in range(3):  # the bones out of the pelvis start at the cell's middle
            assert round((k + 0.5) * width, 9) in starts


def test_a_take_of_one_frame_shows_its_point_on_a_seconds_axis(mpl, tiny_body):
    one = motion_from_arrays(motion_arrays(T=1, seed=0))
    fig = draw_figure([("one", one)], BodyModel(tiny_body),
                      FigureSpec(joints=(4,), frames=2, width=600))  # fmt: skip
    ax = fig.axes[0]
    assert ax.get_xlim() == (0.0, 1 / 30)  # was (0, 1e-9)
    assert ax.lines[0].get_marker() == "o"  # a single frame: a dot, not an empty line
