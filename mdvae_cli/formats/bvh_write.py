"""Writing BVH files (their Euler angles: ``geometry.euler.rotmat_to_euler``).

A file read by :func:`mdvae_cli.formats.bvh.load_bvh` keeps its :class:`BvhLayout` (the header
verbatim, the channel layout, every frame as read); :func:`write_bvh` writes new channel values
under that same header, so hierarchy, names, offsets, channel order and frame time stay the
file's own. :func:`bvh_text` builds a file from scratch (``mdvae export-bvh``).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterable, Iterator
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from mdvae_cli.fileio import write_atomic

#: digits after the decimal point in written channel values (0.000001 deg, 0.000001 unit)
DECIMALS = 6


#: motion rows formatted and written at a time (a long take's whole text at once was
#: several times the file's size in memory: its lines, their join and its bytes)
ROWS_PER_PIECE = 4096


#: values at or above this are written by Python's formatting (their scaled integers would
#: not be exact in float64)
_FAST_LIMIT = 1e8


def format_rows(data: np.ndarray) -> str:
    """Channel values as BVH motion lines (``DECIMALS`` decimals, space separated), as
    ``"%.6f"`` writes them.  data: (n, C)"""
    data = np.asarray(data, dtype=np.float64)
    if data.ndim != 2 or data.size == 0 or DECIMALS != 6:
        return _format_rows_slow(data)
    if not (np.isfinite(data).all() and np.abs(data).max() < _FAST_LIMIT):
        return _format_rows_slow(data)
    text = _fixed_point_text(data.ravel(), data.shape[1])
    return text.tobytes().decode("ascii")


def _format_rows_slow(data: np.ndarray) -> str:
    """:func:`format_rows` by numpy's own text writer."""
    buf = io.StringIO()
    np.savetxt(buf, np.atleast_2d(data), fmt=f"%.{DECIMALS}f", delimiter=" ")
    return buf.getvalue() if np.size(data) else ""


def _scaled(x: np.ndarray) -> np.ndarray:
    """|x| in millionths, rounded exactly as ``"%.6f"`` rounds (half to even on the exact
    binary value): ``rint`` of the float product, or Python's formatting where the product
    lies too close to a half to tell.  x: (N,) finite, |x| < _FAST_LIMIT -> (N,) int64"""
    y = np.abs(x) * 1e6
    q = np.rint(y)
    near = np.abs(np.abs(y - np.floor(y)) - 0.5) <= 1e-15 * y + 1e-300
    out = q.astype(np.int64)
    for i in np.flatnonzero(near):
        out[i] = int(f"{abs(float(x[i])):.6f}".replace(".", ""))
    return out


def _words(texts: list[str]) -> np.ndarray:
    """Texts of up to four ASCII characters as 4-byte words, right-aligned (0 bytes on the
    left: no character), in the machine's byte order.  -> (len(texts),) uint32"""
    raw = b"".join(t.encode("ascii").rjust(4, b"\0") for t in texts)
    return np.frombuffer(raw, dtype=np.uint32)


#: four-byte words of 0..999: zero-padded; as the leading digits of a number, then with a
#: minus sign (1000 + v); '.' and three digits; three digits and a space, or a newline
_PADDED = _words([f"{v:03d}" for v in range(1000)])
_LEADING = _words([f"{v}" for v in range(1000)] + [f"-{v}" for v in range(1000)])
_POINT = _words([f".{v:03d}" for v in range(1000)])
_SPACE, _NEWLINE = (_words([f"{v:03d}{end}"[-4:] for v in range(1000)]) for end in " \n")


def _fixed_point_text(x: np.ndarray, columns: int) -> np.ndarray:
    """The ASCII bytes of ``"%.6f"`` of every value, a space after each and a newline after
    every ``columns``-th: each value a row of 4-byte words (its integer part's three-digit
    groups, '.' and three decimals, three decimals and the separator), read out without the
    empty bytes.  x: (N,) |x| < _FAST_LIMIT -> (bytes,) uint8"""
    whole, frac = (v.astype(np.int32) for v in np.divmod(_scaled(x), 10**6))
    groups = -(-len(str(int(whole.max()))) // 3)  # three-digit groups of the integer part
    grid = np.empty((x.size, groups + 2), dtype=np.uint32)
    hi, lo = np.divmod(frac, 1000)
    grid[:, groups] = _POINT[hi]
    grid[:, groups + 1] = _SPACE[lo]
    ends = slice(columns - 1, None, columns)
    grid[ends, groups + 1] = _NEWLINE[lo[ends]]
    minus = 1000 * np.signbit(x)
    rest = whole
    for g in range(groups):  # from the right: padded where more digits follow, else leading
        rest, part = np.divmod(rest, 1000)
        lead = _LEADING[part + minus]
        if g:
            lead = np.where(part > 0, lead, 0)  # no digits this far left
        grid[:, groups - 1 - g] = np.where(rest > 0, _PADDED[part], lead)
    text = grid.view(np.uint8)
    return text[text > 0]


def line_ending(text: str) -> str:
    """The line ending a text's lines use: CR LF (a file made on Windows), CR alone (an old
    Mac file) or LF."""
    if "\r\n" in text:
        return "\r\n"
    return "\r" if "\r" in text else "\n"


def motion_pieces(
    header: str,
    data: np.ndarray,
    frame_time: str,
    labels=("Frames: ", "Frame Time: "),
    rows_map: Callable = map,
) -> Iterator[str]:
    """A BVH file in pieces: ``header`` (through the MOTION line), the frame count, the frame
    time as given (each after its word in ``labels``, as the file spelled it), then the rows of
    ``data`` (F, C), ``ROWS_PER_PIECE`` at a time; every line ends as the header's lines do
    (:func:`line_ending`). rows_map: how the pieces' rows are formatted, ``map(fn, starts)``
    or one that keeps the order and runs them side by side (``workers.map_in_order``)."""
    nl = line_ending(header)
    frames, time = labels  # as the file spells them
    yield f"{header.rstrip()}{nl}{frames}{data.shape[0]}{nl}{time}{frame_time}{nl}"

    def piece(start: int) -> str:
        rows = format_rows(data[start : start + ROWS_PER_PIECE])
        return rows if nl == "\n" else rows.replace("\n", nl)

    yield from rows_map(piece, range(0, data.shape[0], ROWS_PER_PIECE))


def motion_text(header: str, data: np.ndarray, frame_time: str) -> str:
    """:func:`motion_pieces` as one string."""
    return "".join(motion_pieces(header, data, frame_time))


def write_text(
    path: Path | str,
    text: str | Iterable[str],
    forbid: tuple[Path, ...] = (),
    encoding: str = "utf-8",
) -> None:
    """Write ``text`` (a string, or its pieces in order) atomically, newlines as given; a name
    ending in ``.gz`` (any case) is gzip-compressed. encoding: the one the text was read with
    (``source.decode_text``): ``"utf-8"`` (bytes a reader kept with "surrogateescape" as they
    were), ``"utf-8-sig"`` (a byte-order mark first) or ``"latin-1"``."""
    path = Path(path)
    pieces = (text,) if isinstance(text, str) else text
    codec = "utf-8" if encoding == "utf-8-sig" else encoding

    def write(tmp: Path) -> None:
        raw = open(tmp, "wb")  # noqa: SIM115 (closed below)
        fh = raw
        if path.suffix.lower() == ".gz":
            import gzip

            # the name gzip keeps inside (``gunzip -N``) is the output's, not the temporary's
            fh = gzip.GzipFile(filename=path.name, mode="wb", compresslevel=6, fileobj=raw)
        with raw, fh:
            if encoding == "utf-8-sig":
                fh.write(b"\xef\xbb\xbf")
            for piece in pieces:
                fh.write(piece.encode(codec, errors="surrogateescape"))

    write_atomic(path, write, forbid=forbid)


def frame_time_text(fps: float, like: str) -> str:
    """``1 / fps`` written as ``like`` (a file's own ``Frame Time``) is: as many decimals, or
    significant digits in exponent form, but at least 5 significant digits
    (``frame_time_text(60, "0.033333")`` is ``"0.016667"``)."""
    seconds = 1.0 / fps
    like = like.strip()
    try:
        exponent = Decimal(like).as_tuple().exponent
    except InvalidOperation:
        exponent = -6
    exponent = exponent if isinstance(exponent, int) else -6
    if "e" in like.lower():
        digits = len(like.lower().split("e")[0].replace("-", "").replace(".", "")) - 1
        return f"{seconds:.{max(digits, 4)}e}"
    least = 4 - math.floor(math.log10(seconds))  # decimals for 5 significant digits
    return f"{seconds:.{max(-exponent, least, 0)}f}"


def write_bvh(
    layout, data: np.ndarray, path: Path | str, forbid: tuple[Path, ...] = (),
    fps: float | None = None, rows_map: Callable = map,
) -> None:  # fmt: skip
    """Write every frame ``data`` (F, C) under the file's own header (``layout``: a
    :class:`~mdvae_cli.formats.bvh.BvhLayout`), atomically, in the file's own encoding and
    line endings. fps: the rate to write when it is not the file's own (``--fps``): its
    Frame Time as the file writes one (:func:`frame_time_text`); None keeps the file's.
    rows_map: as :func:`motion_pieces` takes it."""
    frame_time = layout.frame_time if fps is None else frame_time_text(fps, layout.frame_time)
    pieces = motion_pieces(layout.header, data, frame_time, layout.labels, rows_map)
    write_text(path, pieces, forbid=forbid, encoding=layout.encoding)


def bvh_text(
    names: list[str],
    parents: list[int],
    offsets: np.ndarray,
    ends: dict[int, np.ndarray],
    data: np.ndarray,
    frame_time: float,
    order: str = "ZXY",
) -> str:
    """A BVH file from scratch: the root with 6 channels (position, then rotation in
    ``order``), every other joint with 3 rotation channels, an End Site below each joint in
    ``ends`` (joint -> its offset).  offsets: (J, 3) file units; data: (F, 3 + 3 J): the root
    position, then each joint's angles in joint index order (written in the file's
    depth-first order)."""
    kids: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        kids.setdefault(p, []).append(j)
    rot = " ".join(f"{a}rotation" for a in order)
    lines = ["HIERARCHY"]

    def block(j: int, depth: int) -> None:
        pad = "\t" * depth
        word = "ROOT" if parents[j] < 0 else "JOINT"
        lines.append(f"{pad}{word} {names[j]}")
        lines.append(pad + "{")
        off = " ".join(f"{v:.{DECIMALS}f}" for v in offsets[j])
        lines.append(f"{pad}\tOFFSET {off}")
        pos = "Xposition Yposition Zposition " if parents[j] < 0 else ""
        lines.append(f"{pad}\tCHANNELS {6 if parents[j] < 0 else 3} {pos}{rot}")
        for k in kids.get(j, []):
            block(k, depth + 1)
        if j in ends:
            end = " ".join(f"{v:.{DECIMALS}f}" for v in ends[j])
            lines.extend([f"{pad}\tEnd Site", pad + "\t{", f"{pad}\t\tOFFSET {end}", pad + "\t}"])
        lines.append(pad + "}")

    block(0, 0)
    lines.append("MOTION")
    order_j = [names.index(line.split(None, 1)[1]) for line in lines
               if line.strip().startswith(("ROOT ", "JOINT "))]  # fmt: skip
    cols = [0, 1, 2] + [3 + 3 * j + k for j in order_j for k in range(3)]
    return motion_text("\n".join(lines), data[:, cols], f"{frame_time:.8g}")
