"""``mdvae plot`` and the drawing it stands on: PNG files, the bitmap font, the raster and SVG
canvases, the before/after figure and the command."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
import zlib

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.view.canvas import RasterCanvas, SvgCanvas, mix, rgb
from mdvae_cli.view.figure import FigureSpec, draw_figure, envelope, joint_index, nice_ticks
from mdvae_cli.view.font import GLYPHS, glyph, text_mask, text_size
from mdvae_cli.view.png import decode_png, encode_png
from tests.conftest import motion_arrays

# --- PNG -------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 1, 3), (17, 33, 3), (8, 5, 4)])
def test_png_round_trip(shape):
    img = np.random.default_rng(0).integers(0, 256, size=shape).astype(np.uint8)
    data = encode_png(img)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert (decode_png(data) == img).all()


def reference_filter(kind: int, row: np.ndarray, prev: np.ndarray, bpp: int) -> np.ndarray:
    """PNG row filtering as the specification writes it (byte by byte)."""
    out = np.zeros_like(row)
    for i in range(len(row)):
        a = int(row[i - bpp]) if i >= bpp else 0
        b = int(prev[i])
        c = int(prev[i - bpp]) if i >= bpp else 0
        pred = [0, a, b, (a + b) // 2][kind] if kind < 4 else None
        if kind == 4:
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            pred = a if pa <= pb and pa <= pc else b if pb <= pc else c
        out[i] = (int(row[i]) - pred) & 0xFF
    return out


def test_png_decoder_undoes_every_row_filter():
    """Rows filtered with each of the five filters (as a browser's encoder mixes them)."""
    rng = np.random.default_rng(1)
    H, W, C = 10, 7, 3
    img = rng.integers(0, 256, size=(H, W, C)).astype(np.uint8)
    rows, prev = [], np.zeros(W * C, np.uint8)
    for y in range(H):
        row = img[y].reshape(-1)
        kind = y % 5
        rows.append(bytes([kind]) + reference_filter(kind, row, prev, C).tobytes())
        prev = row

    def chunk(kind, data):
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b""))  # fmt: skip
    assert (decode_png(data) == img).all()
    with pytest.raises(InputError):
        decode_png(b"GIF89a")


# --- font ------------------------------------------------------------------------------------


def test_font_covers_printable_ascii_and_draws_known_glyphs():
    assert all(chr(c) in GLYPHS for c in range(32, 127)) and "°" in GLYPHS
    assert glyph("A")[0].tolist() == [False, True, True, True, False]  # .###.
    assert glyph("A")[3].all()  # the bar
    assert not glyph(" ").any()
    box = glyph("\u2603")  # unknown: a box
    assert box[0].all() and box[-1].all() and not box[1:-1, 1:-1].any()
    assert text_size("abc", 2) == (34, 14) and text_mask("abc", 2).shape == (14, 34)
    assert text_mask("", 1).shape == (7, 0)


# --- canvases --------------------------------------------------------------------------------


def test_raster_line_is_antialiased_and_exact_where_it_should_be():
    c = RasterCanvas(40, 20, "#ffffff")
    c.line(5, 10, 35, 10, "#000000", width=2.0)  # covers rows 9 and 10 fully
    img = c.image()
    assert (img[9:11, 8:32] == 0).all()
    assert (img[7, :] == 255).all() and (img[12, :] == 255).all()
    c = RasterCanvas(40, 20, "#ffffff")
    c.line(5, 10.25, 35, 10.25, "#000000", width=1.0)  # straddles two rows: both partly dark
    col = c.image()[:, 20, 0]
    assert 0 < col[9] < 255 and 0 < col[10] < 255 and col[9] > col[10]


def test_raster_disc_area_and_rect_and_text():
    c = RasterCanvas(60, 60, "#000000")
    c.circle(30, 30, 10, "#ffffff")
    area = c.pixels[..., 0].sum()
    assert abs(area - np.pi * 100) < 2.0
    c = RasterCanvas(10, 10, "#000000")
    c.rect(2, 3, 4, 5, "#ffffff")
    assert c.pixels[..., 0].sum() == pytest.approx(20.0)
    c.rect(0, 0, 0.5, 10, "#ffffff")  # half a pixel wide: half covered
    assert c.pixels[5, 0, 0] == pytest.approx(0.5)
    c = RasterCanvas(50, 20, "#ffffff")
    c.text(2, 2, "Hi", "#ff0000", scale=2)
    red = (c.image()[..., 0] == 255) & (c.image()[..., 1] == 0)
    assert red.sum() == text_mask("Hi", 2).sum()
    c.text(-5, -3, "clipped", "#000000")  # partly outside: drawn where it can be
    c.text(2, 2, "v", "#000000", vertical=True)


def test_colours():
    assert np.allclose(rgb("#ff8000"), [1.0, 128 / 255, 0.0])
    assert mix("#000000", "#ffffff", 0.5) == "#808080"


def test_svg_canvas_is_valid_xml_with_the_elements_drawn():
    c = SvgCanvas(100, 50)
    c.line(0, 0, 10, 10, "#123456")
    c.polyline(np.array([[0, 0], [1, 1], [np.nan, 0], [2, 2], [3, 3]]), "#000000")
    c.rect(1, 1, 5, 5, "#ff0000")
    c.circle(5, 5, 2, "#00ff00")
    c.text(3, 3, "a < b & c", "#000000")
    c.text(3, 3, "up", "#000000", vertical=True)
    root = ET.fromstring(c.to_bytes())
    tags = [el.tag.split("}")[1] for el in root]
    assert tags.count("polyline") == 2  # the NaN breaks the line in two
    assert tags.count("text") == 2 and tags.count("rect") == 2 and "circle" in tags
    assert root.attrib["width"] == "100"


# --- the figure ------------------------------------------------------------------------------


def test_helpers():
    assert nice_ticks(0, 1.0).tolist() == pytest.approx([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    assert nice_ticks(-3, 47).tolist() == [0, 10, 20, 30, 40]
    t = np.arange(1000) / 100.0
    v = np.sin(t)
    tt, vv = envelope(t, v, 50, 0.0, 10.0)
    assert len(tt) == 100 and vv.max() == v.max() and vv.min() == v.min()
    assert len(envelope(t[:60], v[:60], 50, 0.0, 0.6)[0]) == 60  # few frames: kept
    assert joint_index("left knee") == 4 == joint_index("4") == joint_index("Left_Knee")
    with pytest.raises(InputError, match="unknown joint"):
        joint_index("tail")
    for bad in (FigureSpec(series="x"), FigureSpec(joints=(22,)), FigureSpec(frames=0)):
        with pytest.raises(InputError):
            bad.validate()


def test_figure_draws_every_motion_in_its_colour(tiny_body):
    items = [
        (f"m{i}.npz", motion_from_arrays(motion_arrays(T=40 + 20 * i, seed=i))) for i in range(3)
    ]
    spec = FigureSpec(joints=(4, 15), frames=4, width=800)  # the head has no bend: still drawn
    canvas = draw_figure(items, BodyModel(tiny_body), spec)
    img = decode_png(canvas.to_bytes())
    assert img.shape[1] == 800 and img.shape[0] == canvas.height
    for color in ("#d9480f", "#1c7ed6", "#2b8a3e"):
        exact = (img == (255 * rgb(color)).round().astype(np.uint8)).all(-1)
        assert exact.sum() > 200, color
    svg = draw_figure(items, BodyModel(tiny_body), FigureSpec(series="bend"), svg=True)
    root = ET.fromstring(svg.to_bytes())
    assert sum(el.tag.endswith("polyline") for el in root) >= 3


def test_plot_command_png_and_svg(tmp_path, make_motion_file):
    a = make_motion_file("noisy.npz", T=50)
    b = make_motion_file("clean.npz", T=50, seed=1)
    for name in ("fig.png", "fig.svg"):
        out = tmp_path / name
        args = ["plot", str(a), str(b), "-o", str(out), "--joint", "left_hip", "--frames", "3"]
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, result.output
        data = out.read_bytes()
        if name.endswith("png"):
            assert decode_png(data).shape[1] == 1400
        else:
            assert ET.fromstring(data).attrib["width"] == "1400"
    for args, message in (
        (["-o", str(tmp_path / "f.jpg")], "must end in"),
        (["-o", str(tmp_path / "f.png"), "--joint", "tail"], "unknown joint"),
    ):
        result = CliRunner().invoke(cli, ["plot", str(a), *args])
        assert result.exit_code == 1 and message in result.output
        assert result.output.startswith("error:")
