"""Writing AMC files: new values under the file's own header, frame numbers and bone lines.

A take read by :func:`mdvae_cli.formats.asfamc.load_amc` keeps its
:class:`~mdvae_cli.formats.asfamc.AmcLayout`; :func:`write_amc` writes new values with it: the
header verbatim, every frame under its own number, each frame's bones in the order it listed
them (a bone a frame left out stays out), with the file's line ending; a frame the file lacked
(a missing frame number: a hole) in its place, listing the bones of the frame before it, unless
the holes are to stay as they came (``gaps=False``). Frames to be holes (``drop``: ``add-noise
--drop-frames``) are left out, their numbers missing: the holes the reader reads
(``formats.amc_frames``). A value that changed by
less than half the last written decimal is written exactly as the file had it; a new one with
:data:`DECIMALS` decimals (:data:`RADIAN_DECIMALS` for angles in radians), trailing zeros
dropped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mdvae_cli.formats.asfamc import AmcLayout
from mdvae_cli.formats.bvh_write import write_text

#: decimals of new values in degrees or in length units (0.000001 deg, 0.000001 unit)
DECIMALS = 6
#: decimals of new angles in radians (1e-8 rad = 0.0000006 deg)
RADIAN_DECIMALS = 8


def format_value(value: float, decimals: int) -> str:
    """``9.3721600`` -> ``9.37216``; ``-0.0000001`` -> ``0`` (no ``-0``)."""
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _decimals(layout: AmcLayout, bone: str) -> list[int]:
    angle = DECIMALS if layout.degrees else RADIAN_DECIMALS
    return [angle if d.startswith("r") else DECIMALS for d in layout.dofs(bone)]


def amc_text(
    layout: AmcLayout,
    values: dict[str, np.ndarray],
    gaps: bool = True,
    drop: np.ndarray | None = None,
) -> str:
    """The AMC file of ``layout`` with ``values`` (bone -> (F, n), every frame of the file; a
    bone left out keeps the file's values). gaps: write the frames the file lacked (its
    missing frame numbers, ``AmcLayout.added``: filled), else the frames it came with alone.
    drop: (F,) bool, frames left out as well (holes: their numbers missing)."""
    lines: dict[str, list[str]] = {}  # bone -> its line in each frame
    for bone, old in layout.values.items():
        tokens = layout.tokens[bone].copy()
        new = np.asarray(values.get(bone, old), dtype=np.float64)
        if new.shape != old.shape:
            raise ValueError(f"bone {bone}: {new.shape} values for {old.shape}")
        for i, dec in enumerate(_decimals(layout, bone)):
            written = tokens[:, i] != None  # noqa: E711 (elementwise)
            changed = np.abs(new[:, i] - old[:, i]) >= 0.5 * 10.0**-dec
            rows = np.flatnonzero(written & (changed | (tokens[:, i] == "")))  # "": added
            tokens[rows, i] = [format_value(v, dec) for v in new[rows, i]]
        # a row of None: a frame that did not list the bone (its line is not written)
        lines[bone] = [bone + "".join(" " + t for t in row) if not row or row[0] is not None
                       else "" for row in tokens.tolist()]  # fmt: skip
    nl = layout.newline
    out = [layout.header]
    skip = np.zeros(len(layout.frames), bool) if gaps or layout.added is None else layout.added
    skip = skip if drop is None else skip | np.asarray(drop, bool)
    for f, number in enumerate(layout.frames):
        if skip[f]:
            continue
        out.append(number + nl)
        out.extend(lines[bone][f] + nl for bone in layout.bones[f])
    return "".join(out)


def write_amc(
    layout: AmcLayout,
    values: dict[str, np.ndarray],
    path: Path | str,
    forbid: tuple = (),
    gaps: bool = True,
    drop: np.ndarray | None = None,
) -> None:
    """Write :func:`amc_text` atomically; a name ending in ``.gz`` is gzip-compressed."""
    write_text(path, amc_text(layout, values, gaps, drop), forbid=forbid)
