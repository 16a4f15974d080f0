"""Read pickled *data* files without running code: plain pickles, joblib dumps, torch files,
``.npy``/``.npz`` with object arrays. What comes back is numpy arrays, numbers, strings and plain
containers (dict, list, tuple), nothing else.

Video pipelines save their results as pickles (WHAM, VIBE, PARE, PHALP through joblib; HybrIK
and AIST++ with ``pickle``; GVHMR with ``torch.save``; TRAM and ROMP as object arrays in
``np.save``/``np.savez``). ``formats.data_files.load_data`` opens all of them with the unpickler
here, which knows a short list of globals, each replaced by a stand-in that builds data:

* numpy arrays, dtypes and scalars (``numpy.core``/``numpy._core`` ``multiarray._reconstruct``,
  ``scalar``, ``numeric._frombuffer``, ``numpy.ndarray``, ``numpy.dtype``);
* ``collections.OrderedDict`` and ``collections.defaultdict`` (read as plain dicts; the default
  factory is dropped), ``builtins`` dict, list, tuple, set, frozenset, complex;
* ``joblib.numpy_pickle.NumpyArrayWrapper``: a stub that records the array's shape, dtype and
  order; the array's raw bytes, which joblib writes into the stream right after the wrapper
  (after a padding-length byte and that padding when the state has
  ``numpy_array_alignment_bytes``), are read by this module, never by joblib;
* torch tensors: ``torch._utils._rebuild_tensor_v2`` (and ``_rebuild_tensor``,
  ``_rebuild_parameter``) build numpy arrays from storages, which come either through
  persistent ids ``('storage', torch.<Type>Storage, key, location, numel)`` pointing at
  ``<archive>/data/<key>`` of a torch zip file, or, in tensors pickled inside other files (TRAM),
  through ``torch.storage._load_from_bytes`` holding torch's legacy stream, parsed here;
  ``torch.Size`` is a tuple.

Any other global (``os.system``, ``builtins.eval``, a class of some library) is refused before
anything is built, with one :class:`InputError` line; nothing of the file has run by then.
"""

from __future__ import annotations

import collections
import functools
import io
import math
import pickle
import zipfile
from collections.abc import Callable
from typing import Any

import numpy as np

from mdvae_cli.body.safe_pickle import numpy_globals
from mdvae_cli.errors import InputError

#: torch storage classes -> numpy dtype of their elements ("bf16": bfloat16, widened)
TORCH_STORAGES = {
    "FloatStorage": "<f4",
    "DoubleStorage": "<f8",
    "HalfStorage": "<f2",
    "BFloat16Storage": "bf16",
    "LongStorage": "<i8",
    "IntStorage": "<i4",
    "ShortStorage": "<i2",
    "CharStorage": "i1",
    "ByteStorage": "u1",
    "BoolStorage": "?",
    "UntypedStorage": "u1",
}
TORCH_MAGIC = 0x1950A86A20F9469CFC6C  # the first pickle of torch's legacy (non-zip) format
#: bytes the tensors of one file may be built into (a tensor may show one stored number many
#: times: a few bytes of storage can claim gigabytes of elements)
MAX_EXPANDED = 512 << 20


class ExpandsTooFar(ValueError):
    """The file's tensors would take more than MAX_EXPANDED bytes."""


class _Budget:
    """The bytes the tensors of one file may still be built into."""

    def __init__(self) -> None:
        self.left = MAX_EXPANDED

    def take(self, nbytes: int) -> None:
        self.left -= nbytes
        if self.left < 0:
            raise ExpandsTooFar()


class _StorageType:
    """Stands for ``torch.<name>Storage`` in a persistent id: only its element dtype is used."""

    def __init__(self, name: str):
        self.name, self.dtype = name, TORCH_STORAGES[name]


class _JoblibArray:
    """Stands for ``joblib.numpy_pickle.NumpyArrayWrapper``: its state says what follows."""

    def __setstate__(self, state: Any) -> None:
        if not isinstance(state, dict):
            raise ValueError("joblib array wrapper without a dict state")
        self.__dict__["state"] = state


class _PendingStorage:
    """A storage of torch's legacy stream, before its bytes (which come after the pickle)."""

    def __init__(self, key: str, dtype: str, numel: int):
        self.key, self.dtype, self.numel = key, dtype, numel


def _storage_array(data: bytes, dtype: str, numel: int, big_endian: bool = False) -> np.ndarray:
    """A storage's elements from its raw bytes.  -> (numel,)"""
    if dtype == "bf16":
        raw = np.frombuffer(data, dtype=">u2" if big_endian else "<u2", count=numel)
        return (raw.astype(np.uint32) << 16).view(np.float32)
    dt = np.dtype(dtype)
    if big_endian and dt.itemsize > 1:
        dt = dt.newbyteorder(">")
    if len(data) < numel * dt.itemsize:
        raise ValueError(f"storage holds {len(data)} bytes, {numel * dt.itemsize} expected")
    return np.frombuffer(data, dtype=dt, count=numel).astype(dt.newbyteorder("="))


def _rebuild_tensor(
    budget: _Budget, storage: Any, offset: int, size: Any, stride: Any, *_ignored: Any
) -> Any:
    """A tensor as a numpy array: ``size`` elements of ``storage`` from ``offset`` with
    ``stride`` (elements), its bytes taken from ``budget``. Storages of torch's legacy stream
    are resolved later."""
    size, stride, offset = tuple(int(s) for s in size), tuple(int(s) for s in stride), int(offset)
    if isinstance(storage, _PendingStorage):
        return ("pending-tensor", storage, offset, size, stride)
    if not isinstance(storage, np.ndarray) or storage.ndim != 1:
        raise ValueError("tensor without a storage")
    return _view(storage, offset, size, stride, budget)


def _view(
    storage: np.ndarray, offset: int, size: tuple, stride: tuple, budget: _Budget
) -> np.ndarray:
    if len(size) != len(stride) or min((*size, *stride, offset), default=0) < 0:
        raise ValueError(f"bad tensor layout: size {size}, stride {stride}, offset {offset}")
    if any(s == 0 for s in size):
        return np.zeros(size, dtype=storage.dtype)
    last = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
    if last >= storage.size:
        raise ValueError(f"tensor of size {size} reaches past its storage of {storage.size}")
    item = storage.itemsize
    budget.take(math.prod(size) * item)  # before the copy: strides of 0 repeat an element
    view = np.lib.stride_tricks.as_strided(
        storage[offset:], shape=size, strides=tuple(s * item for s in stride), writeable=False
    )
    return np.array(view)


def _rebuild_parameter(data: Any, *_ignored: Any) -> Any:
    return data


def _plain_dict(*args: Any) -> dict:
    """``collections.defaultdict(factory)`` read as a plain dict (the factory is dropped)."""
    return {}


def _data_globals(budget: _Budget) -> dict[tuple[str, str], Any]:
    """The globals a data pickle may name, each mapped to what builds its value (tensors take
    their bytes from ``budget``)."""
    allowed = dict(numpy_globals())
    allowed[("collections", "OrderedDict")] = collections.OrderedDict
    allowed[("collections", "defaultdict")] = _plain_dict
    for mod in ("__builtin__", "builtins"):
        for obj in (dict, list, tuple, set, frozenset, complex):
            allowed[(mod, obj.__name__)] = obj
    allowed[("joblib.numpy_pickle", "NumpyArrayWrapper")] = _JoblibArray
    allowed[("torch._utils", "_rebuild_tensor_v2")] = functools.partial(_rebuild_tensor, budget)
    allowed[("torch._utils", "_rebuild_tensor")] = functools.partial(_rebuild_tensor, budget)
    allowed[("torch._utils", "_rebuild_parameter")] = _rebuild_parameter
    allowed[("torch", "Size")] = tuple
    allowed[("torch.storage", "_load_from_bytes")] = _load_torch_bytes
    for name in TORCH_STORAGES:
        allowed[("torch", name)] = _StorageType(name)
    return allowed


class DataUnpickler(pickle._Unpickler):  # the Python unpickler: BUILD can be extended
    """Unpickles data only (module docstring). ``storages(key, dtype, numel)``: the bytes of a
    torch storage named by a persistent id (None: persistent ids are refused); ``label``: the
    file, for messages; ``budget``: what its tensors may take (shared by the file's pickles)."""

    def __init__(
        self,
        file: Any,
        label: str,
        storages: Callable[[str, str, int], np.ndarray | _PendingStorage] | None = None,
        budget: _Budget | None = None,
    ):
        super().__init__(file, encoding="latin1")
        self._label, self._storages, self._file = label, storages, file
        self._budget = budget or _Budget()
        self._allowed = _data_globals(self._budget)

    def find_class(self, module: str, name: str) -> Any:
        found = self._allowed.get((module, name))
        if found is None:
            raise InputError(
                f"{self._label}: refusing to load '{module}.{name}' from the pickle (only "
                "arrays, tensors and plain containers are allowed; nothing was run)"
            )
        return found

    def persistent_load(self, pid: Any) -> Any:
        ok = isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"
        if not ok or self._storages is None or not isinstance(pid[1], _StorageType):
            raise InputError(f"{self._label}: unexpected persistent id in the pickle")
        return self._storages(str(pid[2]), pid[1].dtype, int(pid[4]))

    def _load_build(self) -> None:
        pickle._Unpickler.load_build(self)
        if isinstance(self.stack[-1], _JoblibArray):
            self.stack[-1] = self._joblib_array(self.stack[-1].state)

    dispatch = dict(pickle._Unpickler.dispatch)
    dispatch[pickle.BUILD[0]] = _load_build

    def _joblib_array(self, state: dict) -> np.ndarray:
        """The array a joblib wrapper announces, read from the stream right after it."""
        dtype, shape = state.get("dtype"), tuple(int(n) for n in state.get("shape", ()))
        if not isinstance(dtype, np.dtype) or min(shape, default=0) < 0:
            raise ValueError("joblib array wrapper without a dtype and shape")
        if dtype.hasobject:  # joblib pickles object arrays as a nested pickle
            return DataUnpickler(self._file, self._label, self._storages, self._budget).load()
        if state.get("numpy_array_alignment_bytes") is not None:
            pad = self.read(1)
            if len(pad) != 1:
                raise ValueError("stream ends inside a joblib array")
            self.read(pad[0])
        count = int(np.prod(shape, dtype=np.int64))
        size = count * dtype.itemsize
        remaining = _remaining(self._file)
        if remaining is not None and size > remaining:
            raise ValueError(f"joblib array of {size} bytes, only {remaining} left in the file")
        data = self.read(size)
        if len(data) != size:
            raise ValueError("stream ends inside a joblib array")
        array = np.frombuffer(data, dtype=dtype, count=count).copy()
        if state.get("order") == "F":
            return array.reshape(shape[::-1]).transpose()
        return array.reshape(shape)


def _remaining(file: Any) -> int | None:
    try:
        here = file.tell()
        end = file.seek(0, io.SEEK_END)
        file.seek(here)
        return end - here
    except (AttributeError, OSError, ValueError):
        return None


# --------------------------------------------------------------------------------------------
# containers


def unpickle(file: Any, label: str, storages=None) -> Any:
    return DataUnpickler(file, label, storages).load()


def load_torch_zip(zf: zipfile.ZipFile, label: str) -> Any:
    """A torch zip file (``torch.save`` since 1.6): ``<name>/data.pkl`` with persistent ids
    for storages kept as ``<name>/data/<key>``."""
    names = zf.namelist()
    pkl = next(n for n in names if n == "data.pkl" or n.endswith("/data.pkl"))
    prefix = pkl[: -len("data.pkl")]
    big = prefix + "byteorder" in names and zf.read(prefix + "byteorder").strip() == b"big"
    cache: dict[str, np.ndarray] = {}

    def storage(key: str, dtype: str, numel: int) -> np.ndarray:
        if key not in cache:
            member = f"{prefix}data/{key}"
            if member not in names:
                raise ValueError(f"storage {key!r} missing from the archive")
            cache[key] = _storage_array(zf.read(member), dtype, numel, big)
        return cache[key]

    return unpickle(io.BytesIO(zf.read(pkl)), label, storage)


def load_torch_legacy(data: bytes, label: str) -> Any:
    """torch's legacy stream: pickles of the magic number, the protocol version and the system
    info, the object (storages as persistent ids), the storage keys, then each storage's
    element count (int64) and bytes."""
    f = io.BytesIO(data)
    if unpickle(f, label) != TORCH_MAGIC:
        raise ValueError("not a torch file")
    unpickle(f, label)  # protocol version
    info = unpickle(f, label)
    big = isinstance(info, dict) and info.get("little_endian") is False
    pending: dict[str, _PendingStorage] = {}

    def placeholder(key: str, dtype: str, numel: int) -> _PendingStorage:
        return pending.setdefault(key, _PendingStorage(key, dtype, numel))

    budget = _Budget()
    obj = DataUnpickler(f, label, placeholder, budget).load()
    keys = unpickle(f, label)
    if not isinstance(keys, list):
        raise ValueError("torch file without its storage keys")
    arrays: dict[str, np.ndarray] = {}
    for key in keys:
        head = f.read(8)
        if len(head) != 8:
            raise ValueError("torch file ends before its storages")
        numel = int.from_bytes(head, "big" if big else "little")
        spec = pending.get(str(key))
        dtype = spec.dtype if spec else "u1"
        width = 2 if dtype == "bf16" else np.dtype(dtype).itemsize
        if numel < 0 or numel * width > len(data) - f.tell():
            raise ValueError("torch storage reaches past the end of the file")
        arrays[str(key)] = _storage_array(f.read(numel * width), dtype, numel, big)
    return _resolve(obj, arrays, budget)


def _resolve(obj: Any, arrays: dict[str, np.ndarray], budget: _Budget, depth: int = 0) -> Any:
    """Replace the legacy stream's pending storages and tensors with arrays, in containers."""
    if depth > 200:
        raise ValueError("containers nested too deeply")
    if isinstance(obj, _PendingStorage):
        return arrays[obj.key]
    if isinstance(obj, tuple) and len(obj) == 5 and obj[0] == "pending-tensor":
        return _view(arrays[obj[1].key], *obj[2:], budget)
    if isinstance(obj, dict):
        return type(obj)((k, _resolve(v, arrays, budget, depth + 1)) for k, v in obj.items())
    if isinstance(obj, list | tuple):
        return type(obj)(_resolve(v, arrays, budget, depth + 1) for v in obj)
    return obj


def _load_torch_bytes(data: Any) -> Any:
    """``torch.storage._load_from_bytes``: a storage saved into bytes (legacy stream or zip)."""
    if not isinstance(data, bytes | bytearray):
        raise ValueError("torch storage bytes expected")
    if zipfile.is_zipfile(io.BytesIO(data)):
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            return load_torch_zip(zf, "<tensor>")
    return load_torch_legacy(bytes(data), "<tensor>")
