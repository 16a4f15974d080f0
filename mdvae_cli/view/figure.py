"""``mdvae plot``'s figure, drawn with matplotlib (the optional ``[plot]`` extra): a chosen
series of a few joints for every motion over time, the feet's contacts, and a filmstrip of a
few frames (one row per motion, seen from the side). No pyplot and no global state: a
``matplotlib.figure.Figure`` on its own Agg canvas.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.motion.contacts import FOOT_JOINTS, foot_contacts
from mdvae_cli.motion.motion import Motion
from mdvae_cli.view.page import PALETTE, filled_runs
from mdvae_cli.view.pose import BODY_JOINT_NAMES, BODY_PARENTS, SERIES, joint_series, pose_skeleton

INK, GREY, LIGHT = "#222222", "#777777", "#e6e6e6"
HEAD = 15
#: the height of a filmstrip row, in metres of the scene (a body and its frame's label)
ROW_METRES = 2.5
#: pixels per inch of the figure: ``spec.width`` pixels are ``spec.width / DPI`` inches
DPI = 100
#: what ``mdvae plot`` says when matplotlib is missing
INSTALL = "mdvae plot needs matplotlib: pip install 'mdvae[plot]' (or pip install matplotlib)"


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


def require_matplotlib() -> None:
    """InputError with the way to install it when matplotlib cannot be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise InputError(INSTALL) from None


def side_axis(joints: np.ndarray) -> np.ndarray:
    """The horizontal direction the filmstrip's x axis follows: the root's travel when it
    moves more than 0.5 m, else the direction the body faces.  joints: (T, 22, 3) -> (2,)"""
    travel = joints[-1, 0, :2] - joints[0, 0, :2]
    if np.linalg.norm(travel) > 0.5:
        return travel / np.linalg.norm(travel)
    left = joints[0, 1, :2] - joints[0, 2, :2]  # left hip - right hip; forward = left x up
    forward = np.array([left[1], -left[0]])
    return forward / max(np.linalg.norm(forward), 1e-9)


class _Layout:
    """The figure's rows top to bottom, in inches: ``take(h)`` gives the next row's axes."""

    LEFT, RIGHT, HEADER, PANEL, STRIP = 0.9, 0.25, 1.15, 2.35, 0.2

    def __init__(self, spec: FigureSpec, n: int):
        from matplotlib.figure import Figure

        self.w = spec.width / DPI
        self.cell_w = (self.w - self.LEFT - self.RIGHT) / spec.frames
        self.cell_h = float(np.clip(1.25 * self.cell_w, 1.5, 3.0))
        self.h = self.HEADER + len(spec.joints) * self.PANEL + 0.55 + 2 * n * self.STRIP
        self.h += 0.35 + n * (self.cell_h + 0.1) + 0.15
        self.figure = Figure(figsize=(self.w, self.h), dpi=DPI, facecolor="white")
        self.y = self.h - self.HEADER  # the top of the next row

    def take(self, height: float, gap: float = 0.0):
        bottom = self.y - height
        self.y = bottom - gap
        rect = (self.LEFT / self.w, bottom / self.h, (self.w - self.LEFT - self.RIGHT) / self.w,
                height / self.h)  # fmt: skip
        return self.figure.add_axes(rect)


def draw_figure(items: Sequence[tuple[str, Motion]], body: BodyModel, spec: FigureSpec):
    """The before/after figure of ``items`` ((label, motion) pairs, drawn in this order and
    colour): a title with the legend, one curve panel per joint of ``spec``, the foot contacts
    and the filmstrip.  -> ``matplotlib.figure.Figure`` (``spec.width`` pixels wide at DPI)"""
    spec.validate()
    if not items:
        raise InputError("nothing to plot: give at least one motion file")
    require_matplotlib()
    from matplotlib.lines import Line2D

    posed = [pose_skeleton(m, body) for _, m in items]
    contacts = [foot_contacts(p.joints, m.fps) for p, (_, m) in zip(posed, items, strict=True)]
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(items))]
    # a take of one frame still spans that frame's time (the axis in seconds, not 1e-9)
    duration = max(max(m.duration for _, m in items), max(1 / m.fps for _, m in items))
    times = [(k + 0.5) * duration / spec.frames for k in range(spec.frames)]
    lay = _Layout(spec, len(items))
    fig = lay.figure
    fig.text(0.2 / lay.w, 1 - 0.15 / lay.h, spec.title or " vs ".join(lab for lab, _ in items),
             color=INK, fontsize=15, va="top")  # fmt: skip
    handles = [Line2D([], [], color=c, lw=3) for c in colors]
    filled = [filled_runs(m) for _, m in items]
    labels = [f"{lab} ({m.num_frames} frames, {m.fps:g} Hz{_filled_words(runs)})"
              for (lab, m), runs in zip(items, filled, strict=True)]  # fmt: skip
    fig.legend(handles, labels, loc="upper left", bbox_to_anchor=(0.15 / lay.w, 1 - 0.45 / lay.h),
               ncol=min(len(items), 4), frameon=False, fontsize=10)  # fmt: skip
    for j in spec.joints:
        ax = lay.take(lay.PANEL - 0.6, gap=0.6)
        _curves(ax, j, spec.series, posed, items, colors, duration, times)
        _filled_spans(ax, filled, items, colors)
    _contact_strips(lay.take(2 * len(items) * lay.STRIP, gap=0.35), contacts, items, colors,
                    duration)  # fmt: skip
    _filmstrip(lay, posed, contacts, items, colors, times)
    return fig


def _curves(ax, j, kind, posed, items, colors, duration, times) -> None:
    """One panel: the chosen series of joint ``j`` for every motion over time."""
    label, unit = SERIES[kind]
    ax.set_title(f"{BODY_JOINT_NAMES[j].replace('_', ' ')} {label} ({unit})", loc="left",
                 fontsize=10, color=INK)  # fmt: skip
    series = [joint_series(kind, p, m)[:, j] for p, (_, m) in zip(posed, items, strict=True)]
    for s, (_, m), color in zip(series, items, colors, strict=True):
        ax.plot(np.arange(len(s)) / m.fps, s, color=color, lw=1.6,
                marker="o" if len(s) == 1 else None)  # fmt: skip
    if not any(np.isfinite(s).any() for s in series):
        ax.text(0.02, 0.5, f"no {label} for this joint", transform=ax.transAxes, color=GREY)
    for k, t in enumerate(times):  # where the filmstrip's frames are
        ax.axvline(t, color="#c8c8c8", lw=0.8, zorder=0)
        ax.text(t, 0.97, f" {k + 1}", transform=ax.get_xaxis_transform(), color=GREY,
                va="top", fontsize=8)  # fmt: skip
    ax.set_xlim(0, duration)
    ax.grid(axis="y", color=LIGHT)
    ax.set_xlabel("s", color=GREY, fontsize=8, loc="right")
    ax.tick_params(colors=GREY, labelsize=8)


def _filled_words(runs: list[list[int]]) -> str:
    """``", N filled (shaded)"`` for a motion with frames missing in its file, else ``""``."""
    n = sum(b - a for a, b in runs)
    return f", {n} filled (shaded)" if n else ""


def _filled_spans(ax, filled, items, colors) -> None:
    """Shade each motion's frames missing in its file (``joint_mask``: what the reader or
    ``denoise`` filled) in its colour, with a bar along the top, as the page does: the curve
    there is a fill, not the file's data."""
    for i, (runs, (_, m), color) in enumerate(zip(filled, items, colors, strict=True)):
        for a, b in runs:
            x0, x1 = (a - 0.5) / m.fps, (b - 0.5) / m.fps
            ax.axvspan(x0, x1, color=color, alpha=0.12, lw=0, zorder=0)
            ax.axvspan(x0, x1, ymin=0.97 - 0.03 * i, ymax=1 - 0.03 * i, color=color, lw=0)


def _contact_strips(ax, contacts, items, colors, duration) -> None:
    """Per motion a row for the left foot and one for the right: filled while planted."""
    rows = 2 * len(items)
    for i, (on4, (_, m), color) in enumerate(zip(contacts, items, colors, strict=True)):
        for side in range(2):
            row = rows - 1 - (2 * i + side)
            on = (on4[:, side] | on4[:, side + 2]).astype(int)
            edges = np.flatnonzero(np.diff(np.concatenate([[0], on, [0]])))
            starts, ends = edges[::2], edges[1::2]
            spans = [(a / m.fps, (b - a) / m.fps) for a, b in zip(starts, ends, strict=True)]
            ax.broken_barh([(0, duration)], (row + 0.1, 0.8), color="#f1f1ee")
            ax.broken_barh(spans, (row + 0.1, 0.8), color=color)
    ax.set_xlim(0, duration)
    ax.set_ylim(0, rows)
    ax.set_yticks(np.arange(rows) + 0.5, ["R", "L"] * len(items), fontsize=7, color=GREY)
    ax.set_ylabel("feet", color=GREY, fontsize=8)
    ax.tick_params(colors=GREY, labelsize=8)
    for side in ("top", "right", "left"):
        ax.spines[side].set_visible(False)


def _filmstrip(lay: _Layout, posed, contacts, items, colors, times) -> None:
    """One row per motion, frame k in column k, seen from the side (the far limbs pale), its
    pelvis at the middle of the cell; heights as they are, over the lowest motion's floor."""
    from matplotlib.colors import to_rgb

    axis = side_axis(posed[0].joints)
    across = np.array([-axis[1], axis[0]])
    floor = min(float(np.quantile(p.joints[:, list(FOOT_JOINTS), 2], 0.02)) for p in posed) - 0.05
    frames = [[min(int(round(t * m.fps)), m.num_frames - 1) for _, m in items] for t in times]
    lay.y -= 0.1
    for i, (p, (label, _), color) in enumerate(zip(posed, items, colors, strict=True)):
        ax = lay.take(lay.cell_h, gap=0.1)
        pale = tuple(0.5 * c + 0.5 for c in to_rgb(color))
        width = ROW_METRES * lay.cell_w / lay.cell_h  # metres per column
        for k, t in enumerate(times):
            if i == 0:
                ax.text((k + 0.5) * width, ROW_METRES - 0.25, f"{k + 1}: {t:.2f} s",
                        ha="center", va="bottom", color=GREY, fontsize=8)  # fmt: skip
            J = p.joints[frames[k][i]]
            centre = J[0, :2]  # each body in its own cell, wherever in the world it is
            px = (k + 0.5) * width + (J[:, :2] - centre) @ axis
            py = J[:, 2] - floor
            depth = (J[:, :2] - centre) @ across  # the viewer is on the -across side
            ax.plot([k * width + 0.05, (k + 1) * width - 0.05], [0, 0], color="#bbbbbb", lw=1.5)
            for j in sorted(range(1, len(BODY_PARENTS)), key=lambda j: -depth[j]):
                a = BODY_PARENTS[j]
                near = (depth[j] + depth[a]) / 2 <= 0
                ax.plot(px[[a, j]], py[[a, j]], color=color if near else pale, lw=3,
                        solid_capstyle="round")  # fmt: skip
            ax.add_patch(_disc((px[HEAD], py[HEAD] - 0.05), 0.1, color))
            down = [n for n in range(len(FOOT_JOINTS)) if contacts[i][frames[k][i], n]]
            feet = [FOOT_JOINTS[n] for n in down]
            ax.scatter(px[feet], py[feet], s=40, facecolors="white", edgecolors=INK, zorder=3)
        ax.set_xlim(0, len(times) * width)
        ax.set_ylim(-0.1, ROW_METRES - 0.1)
        ax.set_aspect("equal", adjustable="box")
        ax.axis("off")
        box = ax.get_position()
        lay.figure.text(0.3 / lay.w, box.y0 + box.height / 2, label, rotation=90, color=color,
                        va="center", ha="center", fontsize=10)  # fmt: skip


def _disc(centre, radius, color):
    from matplotlib.patches import Circle

    return Circle(centre, radius, color=color)


def figure_bytes(figure, fmt: str) -> bytes:
    """The figure as a ``"png"`` or ``"svg"`` file's bytes (the same every run; an SVG's text
    stays text)."""
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)
    buf = io.BytesIO()
    metadata = {"Date": None} if fmt == "svg" else {}
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": "mdvae"}):
        figure.savefig(buf, format=fmt, dpi=DPI, metadata=metadata, facecolor="white")
    return buf.getvalue()


def figure_size(figure) -> tuple[int, int]:
    """(width, height) in pixels."""
    w, h = figure.get_size_inches()
    return int(round(w * DPI)), int(round(h * DPI))
