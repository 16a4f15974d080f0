"""Two drawing surfaces with one small API, for figures without a plotting library:
:class:`RasterCanvas` (numpy pixels, anti-aliased lines and discs, bitmap text -> PNG) and
:class:`SvgCanvas` (the same calls as SVG elements -> .svg).

Coordinates are pixels, x to the right, y down; colours are ``"#rrggbb"``. Text is drawn with
the 5 x 7 bitmap font of :mod:`mdvae_cli.view.font` at an integer ``scale``; ``(x, y)`` is the
anchor's top edge.
"""

from __future__ import annotations

import html

import numpy as np

from mdvae_cli.view.font import GLYPH_HEIGHT, text_mask, text_size
from mdvae_cli.view.png import encode_png


def rgb(color: str) -> np.ndarray:
    """``"#rrggbb"`` -> (3,) floats in [0, 1]."""
    value = int(color.lstrip("#"), 16)
    return np.array([(value >> 16) & 255, (value >> 8) & 255, value & 255]) / 255.0


def mix(color: str, other: str, amount: float) -> str:
    """``color`` moved ``amount`` (0..1) of the way to ``other``."""
    c = (1 - amount) * rgb(color) + amount * rgb(other)
    return "#" + "".join(f"{int(round(255 * v)):02x}" for v in c)


def _anchor_x(x: float, width: float, anchor: str) -> float:
    return x - {"start": 0.0, "middle": width / 2, "end": width}[anchor]


class RasterCanvas:
    """An RGB image in floats; every primitive blends its coverage (0..1) into the pixels."""

    def __init__(self, width: int, height: int, background: str = "#ffffff"):
        self.width, self.height = int(width), int(height)
        self.pixels = np.ones((self.height, self.width, 3)) * rgb(background)

    def _blend(self, y0: int, x0: int, coverage: np.ndarray, color: str) -> None:
        region = self.pixels[y0 : y0 + coverage.shape[0], x0 : x0 + coverage.shape[1]]
        region += (rgb(color) - region) * coverage[..., None]

    def _window(self, x0: float, y0: float, x1: float, y1: float):
        """Integer pixel bounds of a box, clipped to the image; None when outside."""
        xa, ya = max(0, int(np.floor(x0))), max(0, int(np.floor(y0)))
        xb, yb = min(self.width, int(np.ceil(x1)) + 1), min(self.height, int(np.ceil(y1)) + 1)
        return None if xa >= xb or ya >= yb else (xa, ya, xb, yb)

    def line(self, x0, y0, x1, y1, color: str, width: float = 1.0) -> None:
        """An anti-aliased segment with round ends."""
        half = width / 2
        box = self._window(min(x0, x1) - half - 1, min(y0, y1) - half - 1,
                           max(x0, x1) + half + 1, max(y0, y1) + half + 1)  # fmt: skip
        if box is None:
            return
        xa, ya, xb, yb = box
        ys, xs = np.mgrid[ya:yb, xa:xb] + 0.5  # pixel centres
        dx, dy = x1 - x0, y1 - y0
        length2 = dx * dx + dy * dy
        t = 0.0 if length2 == 0 else np.clip(((xs - x0) * dx + (ys - y0) * dy) / length2, 0, 1)
        dist = np.hypot(xs - (x0 + t * dx), ys - (y0 + t * dy))
        self._blend(ya, xa, np.clip(half + 0.5 - dist, 0.0, 1.0), color)

    def polyline(self, points: np.ndarray, color: str, width: float = 1.0) -> None:
        """Segments through ``points`` (N, 2); rows with a NaN break the line."""
        p = np.asarray(points, dtype=np.float64)
        for a, b in zip(p[:-1], p[1:], strict=True):
            if np.isfinite(a).all() and np.isfinite(b).all():
                self.line(a[0], a[1], b[0], b[1], color, width)

    def rect(self, x, y, w, h, color: str) -> None:
        """A filled axis-aligned rectangle (edges anti-aliased)."""
        box = self._window(x, y, x + w, y + h)
        if box is None:
            return
        xa, ya, xb, yb = box
        cx = np.clip(
            np.minimum(np.arange(xa, xb) + 1, x + w) - np.maximum(np.arange(xa, xb), x), 0, 1
        )
        cy = np.clip(
            np.minimum(np.arange(ya, yb) + 1, y + h) - np.maximum(np.arange(ya, yb), y), 0, 1
        )
        self._blend(ya, xa, cy[:, None] * cx[None, :], color)

    def circle(self, x, y, r, color: str) -> None:
        """A filled anti-aliased disc."""
        box = self._window(x - r - 1, y - r - 1, x + r + 1, y + r + 1)
        if box is None:
            return
        xa, ya, xb, yb = box
        ys, xs = np.mgrid[ya:yb, xa:xb] + 0.5
        self._blend(ya, xa, np.clip(r + 0.5 - np.hypot(xs - x, ys - y), 0.0, 1.0), color)

    def text(self, x, y, text: str, color: str, scale: int = 2, anchor: str = "start",
             vertical: bool = False) -> None:  # fmt: skip
        """One line of text; ``vertical`` turns it to read bottom-up, ``(x, y)`` then being
        the middle of its left edge."""
        mask = text_mask(text, scale).astype(np.float64)
        if vertical:
            mask = np.rot90(mask)
            x0, y0 = int(round(x)), int(round(y - mask.shape[0] / 2))
        else:
            x0, y0 = int(round(_anchor_x(x, mask.shape[1], anchor))), int(round(y))
        h = min(mask.shape[0], self.height - y0)
        w = min(mask.shape[1], self.width - x0)
        sy, sx = max(0, -y0), max(0, -x0)
        if h > sy and w > sx:
            self._blend(y0 + sy, x0 + sx, mask[sy:h, sx:w], color)

    def image(self) -> np.ndarray:
        """(H, W, 3) uint8."""
        return np.clip(np.rint(self.pixels * 255), 0, 255).astype(np.uint8)

    def to_bytes(self) -> bytes:
        return encode_png(self.image())


class SvgCanvas:
    """The same drawing calls as SVG elements."""

    def __init__(self, width: int, height: int, background: str = "#ffffff"):
        self.width, self.height = int(width), int(height)
        self.parts = [f'<rect width="{self.width}" height="{self.height}" fill="{background}"/>']

    def line(self, x0, y0, x1, y1, color: str, width: float = 1.0) -> None:
        self.parts.append(
            f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" stroke="{color}" '
            f'stroke-width="{width:g}" stroke-linecap="round"/>'
        )

    def polyline(self, points: np.ndarray, color: str, width: float = 1.0) -> None:
        p = np.asarray(points, dtype=np.float64)
        runs, run = [], []
        for q in p:
            if np.isfinite(q).all():
                run.append(f"{q[0]:.1f},{q[1]:.1f}")
            elif run:
                runs.append(run)
                run = []
        runs.append(run)
        for r in (r for r in runs if len(r) > 1):
            self.parts.append(
                f'<polyline points="{" ".join(r)}" fill="none" stroke="{color}" '
                f'stroke-width="{width:g}" stroke-linejoin="round" stroke-linecap="round"/>'
            )

    def rect(self, x, y, w, h, color: str) -> None:
        self.parts.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{w:.1f}" height="{h:.1f}" '
                          f'fill="{color}"/>')  # fmt: skip

    def circle(self, x, y, r, color: str) -> None:
        self.parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r:.1f}" fill="{color}"/>')

    def text(self, x, y, text: str, color: str, scale: int = 2, anchor: str = "start",
             vertical: bool = False) -> None:  # fmt: skip
        size = 9 * scale  # the bitmap font's 7-pixel capitals are ~0.75 of a 9-pixel em
        width = text_size(text, scale)[0]
        body = html.escape(text)
        if vertical:
            base = x + GLYPH_HEIGHT * scale
            self.parts.append(
                f'<text transform="translate({base:.1f},{y:.1f}) rotate(-90)" font-size="{size}" '
                f'font-family="monospace" text-anchor="middle" fill="{color}">{body}</text>'
            )
            return
        self.parts.append(
            f'<text x="{_anchor_x(x, width, anchor):.1f}" y="{y + GLYPH_HEIGHT * scale:.1f}" '
            f'font-size="{size}" font-family="monospace" textLength="{width}" '
            f'lengthAdjust="spacingAndGlyphs" fill="{color}">{body}</text>'
        )

    def to_bytes(self) -> bytes:
        head = (
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{self.width}" '
            f'height="{self.height}" viewBox="0 0 {self.width} {self.height}">'
        )
        return "\n".join([head, *self.parts, "</svg>\n"]).encode("utf-8")
