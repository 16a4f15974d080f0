"""``mdvae plot``'s figure: a chosen series of a few joints for every motion over time, the
feet's contacts, and a filmstrip of a few frames (one row per motion, seen from the side), on a
:class:`~mdvae_cli.view.canvas.RasterCanvas` (PNG) or :class:`~mdvae_cli.view.canvas.SvgCanvas`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.motion.contacts import FOOT_JOINTS, foot_contacts
from mdvae_cli.motion.motion import Motion
from mdvae_cli.view.canvas import RasterCanvas, SvgCanvas, mix
from mdvae_cli.view.font import text_size
from mdvae_cli.view.pose import BODY_JOINT_NAMES, BODY_PARENTS, SERIES, joint_series, pose_skeleton

PALETTE = ("#d9480f", "#1c7ed6", "#2b8a3e", "#9c36b5", "#e8a33d", "#0c8599", "#c2255c")
INK, GREY, LIGHT = "#222222", "#777777", "#e6e6e6"
HEAD = 15


@dataclass(frozen=True)
class FigureSpec:
    """What the figure shows: ``series`` (a key of SERIES) of ``joints`` (indices of the 22
    body joints), ``frames`` filmstrip frames, ``width`` pixels, a ``title``."""

    joints: tuple[int, ...] = (4, 5)
    series: str = "rotation"
    frames: int = 6
    width: int = 1400
    title: str | None = None

    def validate(self) -> FigureSpec:
        if self.series not in SERIES:
            raise InputError(f"unknown series {self.series!r}; choose one of {', '.join(SERIES)}")
        if not self.joints or any(not 0 <= j < len(BODY_JOINT_NAMES) for j in self.joints):
            raise InputError(f"joints must be indices 0..{len(BODY_JOINT_NAMES) - 1}")
        if not 1 <= self.frames <= 20:
            raise InputError(f"the filmstrip takes 1 to 20 frames, got {self.frames}")
        if not 400 <= self.width <= 8000:
            raise InputError(f"the figure width must be 400 to 8000 pixels, got {self.width}")
        return self


def joint_index(name: str) -> int:
    """A body joint by name (``left_knee``, ``left knee``) or index (``4``)."""
    key = name.strip().lower().replace(" ", "_").replace("-", "_")
    if key.isdigit() and int(key) < len(BODY_JOINT_NAMES):
        return int(key)
    if key in BODY_JOINT_NAMES:
        return BODY_JOINT_NAMES.index(key)
    raise InputError(f"unknown joint {name!r}; choose one of {', '.join(BODY_JOINT_NAMES)}")


def nice_ticks(lo: float, hi: float, count: int = 5) -> np.ndarray:
    """Round tick values inside [lo, hi], about ``count`` of them."""
    raw = max(hi - lo, 1e-12) / max(count, 1)
    p = 10.0 ** np.floor(np.log10(raw))
    step = next(m * p for m in (1, 2, 5, 10) if m * p >= raw)
    return np.arange(np.ceil(lo / step) * step, hi + 1e-9 * step, step)


def envelope(times: np.ndarray, values: np.ndarray, pixels: int, t0: float, t1: float):
    """At most ~2 points per pixel column: (min, max) of each column when there are more
    frames than that, else the frames themselves.  -> (times (N,), values (N,))"""
    if len(values) <= 2 * pixels:
        return times, values
    col = np.clip(((times - t0) / max(t1 - t0, 1e-12) * pixels).astype(int), 0, pixels - 1)
    out_t, out_v = [], []
    for c in np.unique(col):
        v = values[col == c]
        v = v[np.isfinite(v)]
        if len(v):
            tc = t0 + (c + 0.5) / pixels * (t1 - t0)
            out_t += [tc, tc]
            out_v += [v.min(), v.max()]
    return np.array(out_t), np.array(out_v)


def side_axis(joints: np.ndarray) -> np.ndarray:
    """The horizontal direction the filmstrip's x axis follows: the root's travel when it
    moves more than 0.5 m, else the direction the body faces.  joints: (T, 22, 3) -> (2,)"""
    travel = joints[-1, 0, :2] - joints[0, 0, :2]
    if np.linalg.norm(travel) > 0.5:
        return travel / np.linalg.norm(travel)
    left = joints[0, 1, :2] - joints[0, 2, :2]  # left hip - right hip; forward = left x up
    forward = np.array([left[1], -left[0]])
    return forward / max(np.linalg.norm(forward), 1e-9)


class _Figure:
    """Lays the figure out top to bottom on one canvas; ``y`` is the next free row."""

    PAD, LEFT, PLOT_H, STRIP = 20, 90, 190, 7

    def __init__(self, items, body: BodyModel, spec: FigureSpec, svg: bool):
        self.items, self.spec = list(items), spec
        self.posed = [pose_skeleton(m, body) for _, m in items]
        pairs = zip(self.posed, items, strict=True)
        self.contacts = [foot_contacts(p.joints, m.fps) for p, (_, m) in pairs]
        self.duration = max(max(m.duration for _, m in items), 1e-9)
        self.colors = [PALETTE[i % len(PALETTE)] for i in range(len(items))]
        self.x0, self.x1 = self.LEFT, spec.width - self.PAD
        self.cell_w = (self.x1 - self.x0) / spec.frames
        self.cell_h = min(300, max(150, int(1.25 * self.cell_w)))
        self.times = [(k + 0.5) * self.duration / spec.frames for k in range(spec.frames)]
        n = len(items)
        height = 82 + len(spec.joints) * (self.PLOT_H + 48) + n * 2 * self.STRIP + 24
        height += 22 + n * (self.cell_h + 10) + self.PAD
        height += 22 * (len(self.legend_rows()) - 1)
        self.canvas = (SvgCanvas if svg else RasterCanvas)(spec.width, height)
        self.y = 0.0

    def X(self, t):
        return self.x0 + np.asarray(t) / self.duration * (self.x1 - self.x0)

    def legend_rows(self) -> list[list[tuple[str, str, float]]]:
        """The legend's entries (text, colour, x), wrapped to the figure's width."""
        rows, x = [[]], self.PAD
        for (label, motion), color in zip(self.items, self.colors, strict=True):
            text = f"{label} ({motion.num_frames} frames, {motion.fps:g} Hz)"
            width = 20 + text_size(text, 2)[0] + 24
            if x + width > self.spec.width and rows[-1]:
                rows.append([])
                x = self.PAD
            rows[-1].append((text, color, x))
            x += width
        return rows

    def header(self) -> None:
        c, spec = self.canvas, self.spec
        c.text(self.PAD, 14, spec.title or " vs ".join(label for label, _ in self.items), INK, 3)
        for r, row in enumerate(self.legend_rows()):
            for text, color, x in row:
                c.rect(x, 50 + 22 * r, 14, 14, color)
                c.text(x + 20, 50 + 22 * r, text, INK, scale=2)
        self.y = 82 + 22 * (len(self.legend_rows()) - 1)

    def curves(self, j: int) -> None:
        """One panel: the chosen series of joint ``j`` for every motion over time."""
        c, kind = self.canvas, self.spec.series
        series = [joint_series(kind, p, m)[:, j] for p, (_, m) in zip(self.posed, self.items,
                                                                      strict=True)]  # fmt: skip
        finite = np.concatenate([s[np.isfinite(s)] for s in series])
        label, unit = SERIES[kind]
        c.text(self.x0, self.y, f"{BODY_JOINT_NAMES[j].replace('_', ' ')} {label} ({unit})", INK)
        top, bottom = self.y + 20, self.y + 20 + self.PLOT_H
        self.y = bottom + 28
        if finite.size == 0:
            c.text(self.x0 + 10, (top + bottom) / 2, f"no {label} for this joint", GREY)
            return
        lo, hi = float(finite.min()), float(finite.max())
        margin = 0.5 if hi - lo < 1e-9 else 0.05 * (hi - lo)
        lo, hi = lo - margin, hi + margin

        def Y(v):
            return bottom - (np.asarray(v) - lo) / (hi - lo) * (bottom - top)

        for v in nice_ticks(lo, hi):
            c.line(self.x0, Y(v), self.x1, Y(v), LIGHT)
            c.text(self.x0 - 8, Y(v) - 7, f"{v + 0.0:g}", GREY, anchor="end")
        for k, t in enumerate(self.times):  # where the filmstrip's frames are
            c.line(self.X(t), top, self.X(t), bottom, "#c8c8c8")
            c.text(self.X(t) + 3, top + 2, str(k + 1), GREY)
        for s, (_, m), color in zip(series, self.items, self.colors, strict=True):
            tt, vv = envelope(np.arange(len(s)) / m.fps, s, int(self.x1 - self.x0), 0.0,
                              self.duration)  # fmt: skip
            c.polyline(np.stack([self.X(tt), Y(vv)], axis=1), color, 1.6)
        c.line(self.x0, bottom, self.x1, bottom, GREY)
        for t in nice_ticks(0, self.duration, max(2, int((self.x1 - self.x0) / 120))):
            c.text(self.X(t), bottom + 6, f"{t:g} s", GREY, anchor="middle")

    def contact_strips(self) -> None:
        """Per motion a row for the left foot and one for the right: filled while planted."""
        c, strip = self.canvas, self.STRIP
        for i, (on4, (_, m), color) in enumerate(zip(self.contacts, self.items, self.colors,
                                                     strict=True)):  # fmt: skip
            for side in range(2):
                row_y = self.y + (2 * i + side) * strip
                c.rect(self.x0, row_y, self.x1 - self.x0, strip - 1, "#f1f1ee")
                on = (on4[:, side] | on4[:, side + 2]).astype(int)
                edges = np.flatnonzero(np.diff(np.concatenate([[0], on, [0]])))
                for a, b in zip(edges[::2], edges[1::2], strict=True):
                    xa, xb = self.X(a / m.fps), self.X(b / m.fps)
                    c.rect(xa, row_y, max(1.0, xb - xa), strip - 1, color)
                c.text(self.x0 - 6, row_y - 0.5, "LR"[side], GREY, scale=1, anchor="end")
        c.text(self.PAD, self.y + len(self.items) * strip - 7, "feet", GREY)
        self.y += len(self.items) * 2 * strip + 24

    def filmstrip(self) -> None:
        """One row per motion, frame k in column k, seen from the side (the far limbs pale)."""
        c, cell_w, cell_h = self.canvas, self.cell_w, self.cell_h
        axis = side_axis(self.posed[0].joints)
        across = np.array([-axis[1], axis[0]])
        floor = min(float(np.quantile(p.joints[:, list(FOOT_JOINTS), 2], 0.02)) for p in self.posed)
        floor -= 0.05
        scale = min((cell_h - 24) / 2.1, cell_w / 1.6)
        for k, t in enumerate(self.times):
            c.text(
                self.x0 + (k + 0.5) * cell_w, self.y, f"{k + 1}: {t:.2f} s", GREY, anchor="middle"
            )
        self.y += 22
        frames = [[min(int(round(t * m.fps)), m.num_frames - 1) for _, m in self.items]
                  for t in self.times]  # fmt: skip
        for i, (p, (label, _), color) in enumerate(zip(self.posed, self.items, self.colors,
                                                       strict=True)):  # fmt: skip
            top = self.y + i * (cell_h + 10)
            ground = top + cell_h - 8
            c.text(self.PAD, top + cell_h / 2, label, color, scale=2, vertical=True)
            for k in range(len(self.times)):
                cx = self.x0 + (k + 0.5) * cell_w
                roots = [q.joints[f, 0, :2] for q, f in zip(self.posed, frames[k], strict=True)]
                centre = np.mean(roots, axis=0)
                J = p.joints[frames[k][i]]
                px = cx + ((J[:, :2] - centre) @ axis) * scale
                py = ground - (J[:, 2] - floor) * scale
                depth = (J[:, :2] - centre) @ across  # the viewer is on the -across side
                c.line(cx - cell_w / 2 + 6, ground, cx + cell_w / 2 - 6, ground, "#bbbbbb", 1.5)

                def shade_of(d, color=color):
                    return color if d <= 0 else mix(color, "#ffffff", 0.5)

                for j in sorted(range(1, len(BODY_PARENTS)), key=lambda j: -depth[j]):
                    a = BODY_PARENTS[j]
                    c.line(px[a], py[a], px[j], py[j], shade_of((depth[j] + depth[a]) / 2), 3)
                c.circle(px[HEAD], py[HEAD] - 0.05 * scale, 0.1 * scale, color)
                for n, joint in enumerate(FOOT_JOINTS):
                    if self.contacts[i][frames[k][i], n]:
                        c.circle(px[joint], py[joint], 4.5, INK)
                        c.circle(px[joint], py[joint], 2.5, "#ffffff")


def draw_figure(items: Sequence[tuple[str, Motion]], body: BodyModel, spec: FigureSpec,
                svg: bool = False):  # fmt: skip
    """The before/after figure of ``items`` ((label, motion) pairs, drawn in this order and
    colour): a header with the legend, one curve panel per joint of ``spec``, the foot
    contacts and the filmstrip.  -> RasterCanvas (``svg`` False) or SvgCanvas"""
    spec.validate()
    if not items:
        raise InputError("nothing to plot: give at least one motion file")
    figure = _Figure(items, body, spec, svg)
    figure.header()
    for j in spec.joints:
        figure.curves(j)
    figure.contact_strips()
    figure.filmstrip()
    return figure.canvas
