"""Compact binary arrays for an HTML page: integers, delta-coded along time, zigzagged,
byte-shuffled, deflated and base64-encoded; the page undoes each step (``viewer_data.js``:
``decodeBlob``).

A (T, C) array is stored channel by channel (C rows of T frames). Motion is smooth, so the
frame-to-frame differences of a channel (order 1), or the differences of those (order 2: the
better one for a clean take at a high frame rate) are small numbers. Zigzag coding maps them
to small unsigned ones (0, -1, 1, -2 -> 0, 1, 2, 3), whose high bytes are nearly all 0; putting
every item's byte 0 first, then every byte 1 (*shuffle*), lets deflate squeeze those runs. Each
array takes the order (1 or 2) that packs smaller. Differences wrap around (integer arithmetic
of the array's width), so any values round-trip exactly.
"""

from __future__ import annotations

import base64
import zlib
from dataclasses import dataclass

import numpy as np

#: numpy dtype -> the page's typed-array name
TYPED_ARRAYS = {"int8": "Int8", "uint8": "Uint8", "int16": "Int16", "int32": "Int32"}


@dataclass(frozen=True)
class Blob:
    """One encoded array: ``text`` (base64) and what the page needs to decode it."""

    text: str
    dtype: str
    frames: int
    channels: int
    delta: int  # 0: values as they are; 1 or 2: differences of that order, zigzagged

    def describe(self, element_id: str) -> dict:
        """The JSON the page reads (``text`` goes into the element ``element_id``)."""
        return {
            "id": element_id,
            "type": TYPED_ARRAYS[self.dtype],
            "frames": self.frames,
            "channels": self.channels,
            "delta": self.delta,
        }


def quantise(values: np.ndarray, step: float, dtype: str) -> np.ndarray:
    """Round ``values / step`` to integers of ``dtype``, clipped to its range."""
    info = np.iinfo(dtype)
    q = np.rint(np.asarray(values, dtype=np.float64) / step)
    return np.clip(q, info.min, info.max).astype(dtype)


def shuffle_bytes(raw: np.ndarray) -> bytes:
    """All items' byte 0, then all byte 1, ...  raw: (N,) little-endian ints -> bytes"""
    size = raw.dtype.itemsize
    return raw.astype(raw.dtype.newbyteorder("<")).view(np.uint8).reshape(-1, size).T.tobytes()


def unshuffle_bytes(data: bytes, dtype: str) -> np.ndarray:
    """Inverse of :func:`shuffle_bytes`.  -> (N,) of ``dtype``"""
    size = np.dtype(dtype).itemsize
    planes = np.frombuffer(data, dtype=np.uint8).reshape(size, -1)
    return planes.T.copy().view(np.dtype(dtype).newbyteorder("<")).reshape(-1).astype(dtype)


def differences(rows: np.ndarray, order: int) -> np.ndarray:
    """Each row's first value, then its differences, ``order`` times.  (C, T) int64 -> (C, T)"""
    for _ in range(order):
        rows = np.concatenate([rows[:, :1], np.diff(rows, axis=1)], axis=1)
    return rows


def zigzag(values: np.ndarray) -> np.ndarray:
    """Integers, read as signed ones of their width, to unsigned ones of that width:
    0, -1, 1, -2 -> 0, 1, 2, 3."""
    bits = values.dtype.itemsize * 8
    wide = values.astype(f"int{bits}").astype(np.int64)
    return ((wide << 1) ^ (wide >> (bits - 1))).astype(f"uint{bits}")


def unzigzag(values: np.ndarray, dtype: str) -> np.ndarray:
    """Inverse of :func:`zigzag`, back to ``dtype`` (of the same width; casts wrap)."""
    wide = values.astype(np.int64)
    return ((wide >> 1) ^ -(wide & 1)).astype(dtype)


def encode_array(
    values: np.ndarray, delta: bool = True, level: int = 6, orders: tuple[int, ...] = (1, 2)
) -> Blob:
    """Encode an integer array (T, C) (or (T,)) frame-major as a :class:`Blob`; with ``delta``,
    as differences of whichever of ``orders`` packs smaller."""
    values = np.asarray(values)
    if values.dtype.name not in TYPED_ARRAYS:
        raise ValueError(f"cannot encode {values.dtype}: use one of {', '.join(TYPED_ARRAYS)}")
    table = values.reshape(values.shape[0], -1)
    T, C = table.shape
    rows = table.T.astype(np.int64)  # (C, T)
    best: tuple[bytes, int] | None = None
    for order in orders if delta else (0,):
        # differences wrap around, as the page's sums do
        wrapped = differences(rows, order).astype(values.dtype).reshape(-1)
        packed = zlib.compress(shuffle_bytes(zigzag(wrapped) if order else wrapped), level)
        if best is None or len(packed) < len(best[0]):
            best = (packed, order)
    packed, order = best
    return Blob(base64.b64encode(packed).decode("ascii"), values.dtype.name, T, C, order)


def decode_array(blob: Blob) -> np.ndarray:
    """Inverse of :func:`encode_array` (what the page does).  -> (T, C)"""
    data = zlib.decompress(base64.b64decode(blob.text))
    if blob.delta:
        unsigned = f"uint{np.dtype(blob.dtype).itemsize * 8}"
        flat = unzigzag(unshuffle_bytes(data, unsigned), blob.dtype)
    else:
        flat = unshuffle_bytes(data, blob.dtype)
    rows = flat.reshape(blob.channels, blob.frames).astype(np.int64)
    for _ in range(int(blob.delta)):
        rows = np.cumsum(rows, axis=1).astype(blob.dtype).astype(np.int64)
    return rows.astype(blob.dtype).T.copy()
