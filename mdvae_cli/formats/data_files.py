"""Data files of any container a video pipeline writes -> plain data, without running code.

:func:`load_data` tells the container from the file's first bytes (:func:`sniff`: a pickle or a
joblib stream, zlib/gzip-compressed or not, a torch zip or legacy file, ``.npy``, ``.npz``) and
reads it through the restricted unpickler of :mod:`mdvae_cli.formats.safe_data`; every failure is
one :class:`InputError` line in the user's words.
"""

from __future__ import annotations

import gzip
import io
import pickle
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.body.safe_pickle import expanded_bytes, one_line
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_regular
from mdvae_cli.formats import safe_data
from mdvae_cli.formats.safe_data import TORCH_MAGIC, load_torch_legacy, load_torch_zip, unpickle

#: bytes a compressed pickle may expand to (a guard against decompression bombs)
MAX_DECOMPRESSED = 512 << 20


def _read_npy(f: Any, label: str) -> np.ndarray:
    """One ``.npy`` array; object arrays through the data unpickler."""
    version = np.lib.format.read_magic(f)
    read_header = {
        (1, 0): np.lib.format.read_array_header_1_0,
        (2, 0): np.lib.format.read_array_header_2_0,
    }.get(version)
    if read_header is None:
        raise ValueError(f"unsupported .npy version {version}")
    shape, fortran, dtype = read_header(f)
    if dtype.hasobject:
        arr = unpickle(f, label)
        if not isinstance(arr, np.ndarray):
            raise ValueError("object .npy that does not hold an array")
        return arr
    count = int(np.prod(shape, dtype=np.int64))
    data = f.read(count * dtype.itemsize)
    if len(data) != count * dtype.itemsize:
        raise ValueError("the .npy file is truncated")
    arr = np.frombuffer(data, dtype=dtype, count=count).copy()
    return arr.reshape(shape[::-1]).transpose() if fortran else arr.reshape(shape)


def _decompress(data: bytes) -> bytes:
    """joblib's zlib (``compress=3``) or gzip streams, bounded by MAX_DECOMPRESSED."""
    if data[:2] == b"\x1f\x8b":
        out = gzip.GzipFile(fileobj=io.BytesIO(data)).read(MAX_DECOMPRESSED + 1)
    else:
        d = zlib.decompressobj()
        out = d.decompress(data, MAX_DECOMPRESSED + 1)
    if len(out) > MAX_DECOMPRESSED:
        raise ValueError(f"decompresses to more than {MAX_DECOMPRESSED >> 20} MiB")
    return out


class UnknownFileType(ValueError):
    """The bytes start like none of the containers :func:`sniff` knows."""


def sniff(data: bytes) -> str:
    """What kind of container ``data`` starts like: "zip", "npy", "zlib", "gzip", "pickle",
    or "" (none of them)."""
    if data[:4] == b"PK\x03\x04":
        return "zip"
    if data[:6] == b"\x93NUMPY":
        return "npy"
    if data[:2] == b"\x1f\x8b":
        return "gzip"
    if data[:1] == b"\x78" and len(data) > 1 and (data[0] * 256 + data[1]) % 31 == 0:
        return "zlib"
    if data[:1] == b"\x80" and len(data) > 1 and 2 <= data[1] <= 5:
        return "pickle"
    return ""


def read_bytes(path: Path) -> bytes:
    """The bytes of the data file at ``path``; InputError (one line) for one that cannot be
    read or is larger than a pose pipeline's output for one video can be."""
    check_regular(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_DECOMPRESSED + 1)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_DECOMPRESSED:
        raise InputError(f"{path}: over {MAX_DECOMPRESSED >> 20} MiB; a pose pipeline's "
                         "output for one video is far smaller (check the file)")  # fmt: skip
    return data


def pickled_container(data: bytes) -> str | None:
    """The pickle container ``data`` (a file's bytes) is, in ``data_write.CONTAINERS`` terms:
    "joblib-zlib" / "joblib-gzip" (a compressed stream, as only joblib writes them), "joblib"
    (a pickle with joblib's in-stream arrays), "pickle"; None for any other container."""
    kind = sniff(data)
    if kind in ("zlib", "gzip"):
        return f"joblib-{kind}"
    if kind == "pickle":
        return "joblib" if b"NumpyArrayWrapper" in data else "pickle"
    return None


def load_data(path: Path | str, data: bytes | None = None) -> Any:
    """The contents of a pickled data file as numpy arrays and plain containers.

    Handles plain pickles, joblib dumps (raw or zlib/gzip-compressed, with in-stream arrays),
    torch files (zip or legacy), ``.npy`` (object arrays too) and ``.npz`` (a dict of its
    members; object members through the data unpickler). ``data``: the file's bytes, when
    already read. Raises InputError (one line) for a refused global or an unreadable file.
    """
    path = Path(path)
    label = str(path)
    if data is None:
        data = read_bytes(path)
    try:
        loaded = _load(data, label, depth=0)
        _check_expanded(loaded, label)
        return loaded
    except InputError:
        raise
    except RecursionError:
        raise InputError(f"{label}: nested too deeply to read") from None
    except safe_data.ExpandsTooFar:
        raise _too_far(label, None) from None
    except MemoryError:
        raise InputError(f"{label}: an array in it is too large to load") from None
    except (
        EOFError,
        IndexError,
        struct.error,  # the unpickler's short read of an opcode's argument: cut off there
        pickle.UnpicklingError,
        zipfile.BadZipFile,
        zlib.error,
        gzip.BadGzipFile,
    ):
        raise InputError(
            f"{label}: the file is truncated or damaged (cannot unpickle it)"
        ) from None
    except UnknownFileType:
        what = "the file is empty" if not data else "not a pickle, joblib, torch or .npy file"
        raise InputError(f"{label}: {what}") from None
    except Exception as exc:  # noqa: BLE001 - any parsing failure is a bad file
        raise InputError(
            f"{label}: not a readable pickle/torch/npy file (damaged: {one_line(exc)})"
        ) from None


def _check_expanded(obj: Any, label: str) -> None:
    """InputError when what ``obj`` holds adds up to more than ``safe_data.MAX_EXPANDED``
    bytes once expanded (:func:`expanded_bytes`); found before any reader stacks them."""
    total = expanded_bytes(obj)
    if total > safe_data.MAX_EXPANDED:
        raise _too_far(label, total)


def _too_far(label: str, total: int | None) -> InputError:
    """The refusal of a file whose arrays would take more than MAX_EXPANDED bytes (``total``:
    how many, when counted)."""
    most = f"{safe_data.MAX_EXPANDED >> 20} MiB"
    amount = f"{total / 2**30:.3g} GiB (over {most})" if total else f"over {most}"
    return InputError(
        f"{label}: its arrays add up to {amount} once the parts it repeats are expanded; a pose "
        "pipeline's output for one video is far smaller (the file is damaged or made to exhaust "
        "memory)"
    )


def _check_members(zf: zipfile.ZipFile, label: str) -> None:
    """InputError for an encrypted member or one that unzips past MAX_DECOMPRESSED (zipfile
    reads no more than a member's stated size, so the limit holds while reading)."""
    total = 0
    for info in zf.infolist():
        if info.flag_bits & 0x1:
            raise InputError(f"{label}: member {info.filename!r} is encrypted (password-protected)")
        total += info.file_size
        if total > MAX_DECOMPRESSED:
            raise InputError(f"{label}: its members unzip past {MAX_DECOMPRESSED >> 20} MiB; a "
                             "pose pipeline's output for one video is far smaller")  # fmt: skip


def _load(data: bytes, label: str, depth: int) -> Any:
    kind = sniff(data)
    if kind in ("zlib", "gzip") and depth == 0:
        return _load(_decompress(data), label, depth + 1)
    if kind == "npy":
        return _read_npy(io.BytesIO(data), label)
    if kind == "zip":
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            _check_members(zf, label)
            names = zf.namelist()
            if any(n == "data.pkl" or n.endswith("/data.pkl") for n in names):
                return load_torch_zip(zf, label)
            out = {}
            for name in names:
                if name.endswith(".npy"):
                    with zf.open(name) as member:
                        out[name[: -len(".npy")]] = _read_npy(io.BytesIO(member.read()), label)
            if not out:
                raise ValueError("a zip archive that is neither a torch file nor an .npz")
            return out
    if kind == "pickle":
        f = io.BytesIO(data)
        first = unpickle(f, label)
        if isinstance(first, int) and first == TORCH_MAGIC:  # an array's == is no bool
            return load_torch_legacy(data, label)
        return first
    raise UnknownFileType()
