"""Compact binary arrays for an HTML page: integers, delta-coded along time, byte-shuffled,
deflated and base64-encoded; the page undoes each step (``viewer_data.js``: ``decodeBlob``).

A (T, C) array is stored channel by channel (C rows of T frames). Motion is smooth, so the
frame-to-frame differences of a channel are small numbers whose high bytes are nearly all 0 or
255; putting every item's byte 0 first, then every byte 1 (*shuffle*), lets deflate squeeze
those runs. Differences wrap around (int16 arithmetic), so any values round-trip exactly.
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
    delta: bool

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


def encode_array(values: np.ndarray, delta: bool = True, level: int = 6) -> Blob:
    """Encode an integer array (T, C) (or (T,)) frame-major as a :class:`Blob`."""
    values = np.asarray(values)
    if values.dtype.name not in TYPED_ARRAYS:
        raise ValueError(f"cannot encode {values.dtype}: use one of {', '.join(TYPED_ARRAYS)}")
    table = values.reshape(values.shape[0], -1)
    T, C = table.shape
    rows = table.T.astype(np.int64)  # (C, T)
    if delta and T > 1:
        rows = np.concatenate([rows[:, :1], np.diff(rows, axis=1)], axis=1)
    wrapped = rows.astype(values.dtype)  # differences wrap around, as the page's sums do
    packed = zlib.compress(shuffle_bytes(wrapped.reshape(-1)), level)
    return Blob(base64.b64encode(packed).decode("ascii"), values.dtype.name, T, C, delta)


def decode_array(blob: Blob) -> np.ndarray:
    """Inverse of :func:`encode_array` (what the page does).  -> (T, C)"""
    flat = unshuffle_bytes(zlib.decompress(base64.b64decode(blob.text)), blob.dtype)
    rows = flat.reshape(blob.channels, blob.frames)
    if blob.delta:
        rows = np.cumsum(rows.astype(np.int64), axis=1).astype(blob.dtype)
    return rows.T.copy()
