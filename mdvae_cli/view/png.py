"""PNG files with the standard library only: write 8-bit RGB images, read 8-bit gray, RGB or
RGBA ones (non-interlaced, every row filter), e.g. a browser's screenshot in a test."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from mdvae_cli.errors import InputError

SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: colour type -> channels (8-bit depth only)
_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def encode_png(image: np.ndarray, level: int = 9) -> bytes:
    """PNG bytes of an image.  image: (H, W, 3) uint8 RGB (or (H, W, 4) RGBA)"""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W, 3 or 4) image, got {image.shape}")
    H, W, C = image.shape
    rows = image.reshape(H, W * C)
    # filter "Sub" (each byte minus the one a pixel to its left): flat areas become zeros
    sub = rows.astype(np.int16)
    sub[:, C:] -= rows[:, :-C]
    raw = np.concatenate([np.ones((H, 1), np.uint8), (sub & 0xFF).astype(np.uint8)], axis=1)
    header = struct.pack(">IIBBBBB", W, H, 8, 2 if C == 3 else 6, 0, 0, 0)
    return (
        SIGNATURE
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
        + _chunk(b"IEND", b"")
    )


def _unfilter_sequential(kind: int, line: list, prev: list, C: int) -> np.ndarray:
    row = list(line)
    for i in range(len(row)):
        a = row[i - C] if i >= C else 0
        b = prev[i]
        if kind == 3:
            row[i] = (line[i] + (a + b) // 2) & 0xFF
        else:
            c = prev[i - C] if i >= C else 0
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            row[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 0xFF
    return np.asarray(row, dtype=np.int32)


def decode_png(data: bytes) -> np.ndarray:
    """The pixels of an 8-bit, non-interlaced PNG.  -> (H, W, C) uint8 (C = 1, 2, 3 or 4)

    Rows filtered with Average or Paeth are undone in pure Python (~1 s per megapixel)."""
    if not data.startswith(SIGNATURE):
        raise InputError("not a PNG file")
    pos, header, idat = len(SIGNATURE), None, []
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise InputError("PNG without a header")
    W, H, depth, colour, _, _, interlace = header
    if depth != 8 or colour not in _CHANNELS or interlace:
        raise InputError(f"unsupported PNG (depth {depth}, colour type {colour}, interlace)")
    C = _CHANNELS[colour]
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8).reshape(H, 1 + W * C)
    out = np.zeros((H, W * C), dtype=np.int32)
    prev = np.zeros(W * C, dtype=np.int32)
    for y in range(H):
        kind, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        if kind == 0:
            row = line
        elif kind == 1:  # Sub: a running sum along the row, per channel
            row = (np.cumsum(line.reshape(W, C), axis=0) & 0xFF).reshape(-1)
        elif kind == 2:
            row = (line + prev) & 0xFF
        elif kind in (3, 4):  # Average, Paeth: pixel by pixel (slow; rare in small images)
            row = _unfilter_sequential(kind, line.tolist(), prev.tolist(), C)
        else:
            raise InputError(f"PNG row {y} has unknown filter {kind}")
        out[y] = row
        prev = row
    return out.astype(np.uint8).reshape(H, W, C)
