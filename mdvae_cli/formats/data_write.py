"""Write a video pipeline's result back in the container it came in: a plain pickle (HybrIK,
AIST++), a joblib stream (WHAM, VIBE, PARE; zlib-compressed: 4D-Humans), a torch file
(GVHMR), ``np.save`` of a dict of tensors (TRAM) or an ``np.savez`` archive (ROMP / BEV's
object arrays, SLAHMR's plain ones). The inverse of
``formats.data_files.load_data`` for the data it returns (arrays, numbers, strings, plain
containers).

Pickles name numpy's array and scalar builders ``numpy.core.multiarray._reconstruct`` /
``scalar``, the names both numpy 1 and numpy 2 load, so that a file written here opens in the
pipeline's own environment, whatever its numpy. A joblib stream is written in joblib's own
format (each array as a ``NumpyArrayWrapper`` followed by its raw bytes), so ``joblib.load``
reads it as it reads the pipeline's file; joblib is not needed to write it.
"""

from __future__ import annotations

import gzip
import io
import pickle
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.fileio import write_atomic

#: containers :func:`write_data` writes ("joblib-zlib": joblib's ``compress=3``,
#: "joblib-gzip": its ``compress=("gzip", 3)``)
CONTAINERS = ("pickle", "joblib", "joblib-zlib", "joblib-gzip", "torch", "npy", "npz")
#: numpy's array and scalar builders under the names every numpy version loads
_NUMPY_NAMES = {
    np.zeros(1).__reduce__()[0]: b"numpy.core.multiarray\n_reconstruct\n",
    np.int64(0).__reduce__()[0]: b"numpy.core.multiarray\nscalar\n",
}
#: joblib's alignment of in-stream array bytes
_JOBLIB_ALIGN = 16


class _DataPickler(pickle._Pickler):  # the Python pickler: its globals can be renamed
    """A protocol-4 pickler that names numpy's builders as every numpy loads them
    (module docstring)."""

    def __init__(self, file: Any):
        super().__init__(file, protocol=4)

    def save_global(self, obj: Any, name: str | None = None) -> None:
        renamed = _NUMPY_NAMES.get(obj) if callable(obj) else None
        if renamed is None:
            super().save_global(obj, name)
            return
        self.write(pickle.GLOBAL + renamed)
        self.memoize(obj)


class _JoblibPickler(_DataPickler):
    """Pickles as ``joblib.dump`` does: each array a ``NumpyArrayWrapper`` whose BUILD is
    followed, outside any frame, by a padding-length byte, the padding and the raw bytes
    (``alignment`` None: no padding, as joblib before 0.12 wrote it)."""

    def __init__(self, file: Any, alignment: int | None = _JOBLIB_ALIGN):
        super().__init__(file)
        self.out, self.alignment = file, alignment

    def save(self, obj: Any, save_persistent_id: bool = True) -> None:
        if not isinstance(obj, np.ndarray) or obj.dtype.hasobject:
            super().save(obj, save_persistent_id)
            return
        self.write(pickle.GLOBAL + b"joblib.numpy_pickle\nNumpyArrayWrapper\n")
        self.write(pickle.EMPTY_TUPLE + pickle.NEWOBJ)
        state = {
            "subclass": np.ndarray,
            "shape": obj.shape,
            "order": "C",
            "dtype": obj.dtype,
            "allow_mmap": True,
        }
        if self.alignment is not None:
            state["numpy_array_alignment_bytes"] = self.alignment
        super().save(state)
        self.write(pickle.BUILD)
        self.framer.commit_frame(force=True)
        if self.alignment is not None:
            pad = self.alignment - (self.out.tell() + 1) % self.alignment
            self.out.write(bytes([pad]) + b"\xff" * pad)
        self.out.write(np.ascontiguousarray(obj).tobytes())


def pickle_bytes(obj: Any, joblib: bool = False, alignment: int | None = _JOBLIB_ALIGN) -> bytes:
    """``obj`` pickled (module docstring), in joblib's stream format with ``joblib`` (its
    arrays padded to ``alignment`` bytes; None: unpadded, older joblib's format)."""
    out = io.BytesIO()
    (_JoblibPickler(out, alignment) if joblib else _DataPickler(out)).dump(obj)
    return out.getvalue()


def as_tensors(obj: Any) -> Any:
    """``obj`` with every numeric array (at any depth of dicts, lists, tuples) a torch tensor:
    what a torch file held before ``load_data`` made its tensors arrays."""
    import torch

    if isinstance(obj, np.ndarray) and obj.dtype.kind in "biuf":
        return torch.from_numpy(np.ascontiguousarray(obj))
    if isinstance(obj, dict):
        return type(obj)((k, as_tensors(v)) for k, v in obj.items())
    if isinstance(obj, list | tuple):
        return type(obj)(as_tensors(v) for v in obj)
    return obj


def write_data(obj: Any, path: Path, container: str, forbid: tuple[Path, ...] = ()) -> None:
    """Write ``obj`` to ``path`` atomically (never onto ``forbid``) in ``container``
    (CONTAINERS). For "torch" and "npy" the arrays become tensors first (:func:`as_tensors`);
    for "npz" ``obj`` is a dict of arrays (the members, as ``np.savez`` takes them)."""
    if container not in CONTAINERS:
        raise ValueError(f"unknown container {container!r}")
    writers: dict[str, Callable[[Path], None]] = {
        "pickle": lambda tmp: tmp.write_bytes(pickle_bytes(obj)),
        "joblib": lambda tmp: tmp.write_bytes(pickle_bytes(obj, joblib=True)),
        "joblib-zlib": lambda tmp: tmp.write_bytes(zlib.compress(pickle_bytes(obj, True), 3)),
        "joblib-gzip": lambda tmp: tmp.write_bytes(
            gzip.compress(pickle_bytes(obj, True), compresslevel=3, mtime=0)
        ),
        "torch": lambda tmp: _torch_save(as_tensors(obj), tmp),
        "npy": lambda tmp: _npy_save(as_tensors(obj), tmp),
        "npz": lambda tmp: _npz_save(obj, tmp),
    }
    write_atomic(Path(path), writers[container], forbid=forbid)


def _torch_save(obj: Any, tmp: Path) -> None:
    import torch

    # into a file object: torch names the archive's folder after a path it is given, here the
    # random temporary name, so that the same result would be written as different bytes
    with open(tmp, "wb") as fh:
        torch.save(obj, fh)


def _npy_save(obj: Any, tmp: Path) -> None:
    holder = np.empty((), dtype=object)
    holder[()] = obj
    with open(tmp, "wb") as fh:
        np.save(fh, holder, allow_pickle=True)


def npy_bytes(a: np.ndarray) -> bytes:
    """One array as an ``.npy`` file: ``np.save``'s header, then the raw bytes, or for an
    object array its pickle (module docstring: numpy 1 and 2 both load it)."""
    a = np.asarray(a)
    header = np.lib.format.header_data_from_array_1_0(a)
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, header)
    if a.dtype.hasobject:
        out.write(pickle_bytes(a))
    else:  # in the order the header names
        out.write(a.tobytes("F" if header["fortran_order"] else "C"))
    return out.getvalue()


def _npz_save(members: dict, tmp: Path) -> None:
    """``np.savez(tmp, **members)``, each member written by :func:`npy_bytes` (stored, not
    compressed, as ``np.savez`` does)."""
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, value in members.items():
            zf.writestr(f"{name}.npy", npy_bytes(np.asarray(value)))
