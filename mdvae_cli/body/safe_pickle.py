"""A restricted unpickler for SMPL-family body-model pickles, with no chumpy or scipy needed.

(Data pickles — video-pipeline outputs, torch and joblib files — are read by ``safe_data``.)

The SMPL pickles as distributed hold ``chumpy`` arrays and a ``scipy.sparse`` joint regressor.
:func:`read_pickle` loads such a file with an unpickler that builds numpy arrays, stands in for
chumpy and scipy.sparse classes (rebuilt from their pickled state only: no code of either
library runs) and refuses every other class. :func:`plain_value` then turns a loaded value into
numpy: chumpy nodes evaluated, sparse matrices densified. Every failure is an
:class:`InputError` with a one-line message.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.errors import InputError


class _PickledObject:
    """A foreign object (chumpy array, scipy sparse matrix) rebuilt from its state only.

    Subclasses are made per pickled class name; no code of the original library runs.
    """

    qualname = ""

    def __setstate__(self, state: Any) -> None:
        if isinstance(state, tuple) and len(state) == 2:  # (__dict__, slot state)
            merged: dict[str, Any] = {}
            for part in state:
                if isinstance(part, dict):
                    merged.update(part)
            state = merged
        if not isinstance(state, dict):
            raise TypeError(f"{self.qualname}: unexpected pickled state {type(state).__name__}")
        self.__dict__["state"] = state


class _ChumpyObject(_PickledObject):
    """A ``chumpy`` array or expression node; the value is in its state (``x``, ``a``...)."""


class _SparseMatrix(_PickledObject):
    """A ``scipy.sparse`` csc/csr/coo matrix, densified with numpy."""


_SPARSE_NAMES = ("csc_matrix", "csc_array", "csr_matrix", "csr_array", "coo_matrix", "coo_array")


def numpy_globals() -> dict[tuple[str, str], Any]:
    """What pickled numpy arrays, dtypes and scalars (and bytes at protocol < 3) name: both
    spellings of numpy's core module (``numpy.core``, numpy >= 2's ``numpy._core``).

    Python-level functions are fresh wrappers per call, so a pickle that sets attributes on
    what it loaded (BUILD) cannot alter the real ones.
    """
    reconstruct = np.zeros(1).__reduce__()[0]  # built-in numpy functions: no settable state
    scalar = np.float64(0).__reduce__()[0]
    frombuffer = np.zeros(1).__reduce_ex__(5)[0]

    def from_buffer(*args: Any) -> np.ndarray:
        return frombuffer(*args)

    def encode(text: str, encoding: str = "utf-8") -> bytes:  # how py3 pickles bytes at proto<3
        if encoding.replace("-", "").replace("_", "").lower() not in ("latin1", "utf8", "ascii"):
            raise TypeError(f"codec {encoding!r} not allowed")
        return text.encode(encoding)

    allowed: dict[tuple[str, str], Any] = {("_codecs", "encode"): encode}
    for core in ("numpy.core", "numpy._core"):
        allowed[(f"{core}.multiarray", "_reconstruct")] = reconstruct
        allowed[(f"{core}.multiarray", "scalar")] = scalar
        allowed[(f"{core}.numeric", "_frombuffer")] = from_buffer
    allowed[("numpy", "ndarray")] = np.ndarray
    allowed[("numpy", "dtype")] = np.dtype
    return allowed


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """The only plain callables a body-model pickle may name: what numpy and copyreg need."""
    import copyreg

    def rebuild(cls: type, base: type, state: Any) -> Any:
        return copyreg._reconstructor(cls, base, state)

    def newobj(cls: type, *args: Any) -> Any:
        return cls.__new__(cls, *args)

    allowed = numpy_globals()
    for mod in ("copy_reg", "copyreg"):
        allowed[(mod, "_reconstructor")] = rebuild
        allowed[(mod, "__newobj__")] = newobj
    for mod in ("__builtin__", "builtins"):
        for obj in (object, set, frozenset, slice, complex, bytearray):
            allowed[(mod, obj.__name__)] = obj
    return allowed


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that builds numpy arrays, stands in for chumpy / scipy sparse, refuses the rest."""

    def __init__(self, file: Any, label: str):
        super().__init__(file, encoding="latin1")
        self._label = label
        self._allowed = _allowed_globals()
        self._stand_ins: dict[tuple[str, str], type] = {}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in self._allowed:
            return self._allowed[(module, name)]
        base: type | None = None
        if name.isidentifier():
            if module == "chumpy" or module.startswith("chumpy."):
                base = _ChumpyObject
            elif module.startswith("scipy.sparse") and name in _SPARSE_NAMES:
                base = _SparseMatrix
        if base is None:
            raise InputError(
                f"body model {self._label}: refusing to load '{module}.{name}' from "
                "the pickle (only numpy, chumpy and scipy.sparse arrays are allowed)"
            )
        key = (module, name)
        if key not in self._stand_ins:
            self._stand_ins[key] = type(name, (base,), {"qualname": f"{module}.{name}"})
        return self._stand_ins[key]


#: bytes a body-model pickle's arrays may take once expanded (SMPL-X's: about 0.3 GB)
MAX_EXPANDED = 1 << 30


def expanded_bytes(obj: Any) -> int:
    """Bytes the arrays and containers of an unpickled ``obj`` take once expanded: an array or
    list counted once for each place that refers to it (a small pickle can repeat one array
    thousands of times, and a reader stacking them would allocate every copy), a tensor by the
    elements it shows, a sparse matrix by its dense size, a foreign object by its state."""
    sizes: dict[int, int] = {}

    def size(o: Any) -> int:
        key = id(o)
        if key in sizes:
            return sizes[key]
        sizes[key] = 0  # a container that holds itself adds nothing more
        if isinstance(o, np.ndarray):
            n = sum(map(size, o.flat)) if o.dtype.hasobject else o.size * o.itemsize
        elif isinstance(o, dict):
            n = sum(size(k) + size(v) for k, v in o.items())
        elif isinstance(o, (list, tuple, set, frozenset)):
            n = sum(size(x) + 8 for x in o)
        elif isinstance(o, _SparseMatrix):
            shape = o.state.get("_shape", o.state.get("shape"))
            dense = math.prod(int(d) for d in shape) * 8 if isinstance(shape, tuple) else 0
            n = max(dense, size(o.state))
        elif isinstance(o, _PickledObject):
            n = size(o.state)
        else:
            n = len(o) if isinstance(o, (bytes, bytearray, str)) else 8
        sizes[key] = n
        return n

    return size(obj)


def read_pickle(path: Path) -> dict[str, Any]:
    name = path.name
    with path.open("rb") as f:
        data = unpickle_stream(f, name)
    if not isinstance(data, dict):
        raise InputError(
            f"body model {name}: pickle holds a {type(data).__name__}, expected a dict"
        )
    return {str(k): v for k, v in data.items()}


def unpickle_stream(f: Any, name: str) -> Any:
    """What a body-model pickle stream holds (numpy arrays, chumpy and scipy.sparse stand-ins,
    plain containers); InputError naming ``name`` for anything else, or too large."""
    try:
        data = _RestrictedUnpickler(f, name).load()
        total = expanded_bytes(data)
    except InputError:
        raise
    except MemoryError:
        raise InputError(
            f"body model {name}: the pickle asks for an array too large for memory"
        ) from None
    except Exception as e:  # noqa: BLE001 - any unpickling failure is a bad file
        truncated = isinstance(e, EOFError) or "truncated" in str(e)
        why = "it is truncated" if truncated else one_line(e).rstrip(".")
        raise InputError(f"body model {name}: not a readable body-model pickle ({why})") from None
    if total > MAX_EXPANDED:
        raise InputError(
            f"body model {name}: its arrays add up to {total / 2**30:.3g} GiB once the parts it "
            f"repeats are expanded (over {MAX_EXPANDED >> 20} MiB); the file is damaged"
        )
    return data


def plain_value(value: Any, label: str, key: str) -> Any:
    """Turn a pickled value into numpy: chumpy nodes evaluated, sparse matrices densified."""
    try:
        return _evaluate(value, depth=0)
    except MemoryError:
        raise InputError(f"body model {label}: {key!r} is too large for memory") from None
    except Exception as e:  # noqa: BLE001 - malformed state of a stand-in object
        raise InputError(f"body model {label}: cannot rebuild {key!r} ({one_line(e)})") from None


def _evaluate(value: Any, depth: int) -> Any:
    if depth > 100:
        raise ValueError("chumpy expression nested too deeply")
    if isinstance(value, _SparseMatrix):
        return _densify(value)
    if not isinstance(value, _ChumpyObject):
        return value
    s, kind = value.state, type(value).__name__

    def arg(term: str) -> np.ndarray:
        if term not in s:
            raise ValueError(f"{value.qualname} without {term!r}")
        return np.asarray(_evaluate(s[term], depth + 1))

    if kind == "Select":
        out = arg("a").ravel()[arg("idxs")]
        return out.reshape(s["preferred_shape"]) if s.get("preferred_shape") is not None else out
    if kind == "Reshape":
        return arg("a").reshape(s["newshape"])
    if kind == "transpose":
        return np.transpose(arg("a"), s.get("axes"))
    if kind in ("add", "subtract", "multiply"):
        return getattr(np, kind)(arg("a"), arg("b"))
    if kind == "Concatenate":
        return np.concatenate([arg(t) for t in s["dterms"]], axis=s.get("axis", 0))
    if "x" in s and (kind in ("Ch", "ChHandle") or not {"a", "b"} & set(s)):
        return arg("x")
    raise ValueError(f"cannot evaluate chumpy object {value.qualname}")


def _densify(matrix: _SparseMatrix) -> np.ndarray:
    """Dense (rows, cols) array from a scipy csc / csr / coo matrix's pickled ``__dict__``."""
    state = matrix.state
    shape = state.get("_shape", state.get("shape"))
    if shape is None or len(shape) != 2:
        raise ValueError("sparse matrix without a 2-d shape")
    rows, cols = int(shape[0]), int(shape[1])
    data = np.asarray(state["data"]).ravel()
    fmt = type(matrix).__name__[:3]  # csc / csr / coo, from the pickled class name
    if fmt in ("csc", "csr"):
        indptr = np.asarray(state["indptr"], dtype=np.int64).ravel()
        index = np.asarray(state["indices"], dtype=np.int64).ravel()
        outer_size = cols if fmt == "csc" else rows
        if len(indptr) != outer_size + 1 or indptr[-1] != len(data) or len(index) != len(data):
            raise ValueError(f"inconsistent {fmt} arrays")
        outer = np.repeat(np.arange(outer_size), np.diff(indptr))
        r, c = (index, outer) if fmt == "csc" else (outer, index)
    else:
        coords = state.get("coords")
        r, c = coords if coords is not None else (state["row"], state["col"])
        r, c = np.asarray(r, dtype=np.int64).ravel(), np.asarray(c, dtype=np.int64).ravel()
    if len(r) != len(data) or len(c) != len(data):
        raise ValueError("sparse index and data arrays differ in length")
    if len(r) and (min(r.min(), c.min()) < 0 or r.max() >= rows or c.max() >= cols):
        raise ValueError("sparse indices out of range")
    dense = np.zeros((rows, cols), dtype=np.float64)
    np.add.at(dense, (r, c), data)
    return dense


def one_line(e: BaseException) -> str:
    """The first line of an exception's message, in words (no exception class names)."""
    if isinstance(e, KeyError) and e.args:
        return f"it refers to {e.args[0]!r}, which it does not hold"
    lines = str(e).strip().splitlines()
    return lines[0] if lines else "no details"
