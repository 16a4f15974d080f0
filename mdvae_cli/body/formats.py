"""Body-model file loaders: SMPL ``.pkl``, SMPL-H / SMPL-X ``.npz`` -> :class:`BodyModelData`.

Plain numpy only: the SMPL pickles as distributed hold ``chumpy`` arrays and a ``scipy.sparse``
joint regressor, and are read here without either library by a restricted unpickler that
rebuilds those objects from their pickled state and refuses every other class.

The model kind is read from the file's kinematic tree (24 joints SMPL, 52 SMPL-H, 55 SMPL-X),
never from its name. Every failure is an :class:`InputError` with a one-line message.
"""

from __future__ import annotations

import pickle
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.body.data import (
    NUM_BODY_JOINTS,
    SMPL_JOINT_NAMES,
    SMPL_MARKER_VERTEX_IDS,
    BodyModelData,
)
from mdvae_cli.errors import InputError

REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights",
                 "kintree_table", "f")  # fmt: skip

#: Vertex count shared by SMPL and SMPL-H meshes (same topology, same marker vertices).
SMPL_NUM_VERTICES = 6890

_FINGERS = ("index", "middle", "pinky", "ring", "thumb")


def _hand_joint_names(side: str) -> tuple[str, ...]:
    return tuple(f"{side}_{finger}{k}" for finger in _FINGERS for k in (1, 2, 3))


#: SMPL-H: the 22 SMPL body joints, then 15 left-hand and 15 right-hand finger joints.
SMPLH_JOINT_NAMES = (
    SMPL_JOINT_NAMES[:NUM_BODY_JOINTS] + _hand_joint_names("left") + _hand_joint_names("right")
)
#: SMPL-X: the 22 body joints, jaw and eyes, then the two hands as in SMPL-H.
SMPLX_JOINT_NAMES = (
    SMPL_JOINT_NAMES[:NUM_BODY_JOINTS]
    + ("jaw", "left_eye", "right_eye")
    + _hand_joint_names("left")
    + _hand_joint_names("right")
)
_KINDS = {24: ("smpl", SMPL_JOINT_NAMES), 52: ("smplh", SMPLH_JOINT_NAMES),
          55: ("smplx", SMPLX_JOINT_NAMES)}  # fmt: skip


def load_body_model(path: Path | str | None = None) -> BodyModelData:
    """Load an SMPL-family body model file, or the built-in body when ``path`` is None.

    Reads an SMPL / SMPL-H / SMPL-X ``.pkl`` (as distributed, chumpy and scipy not needed) or
    ``.npz`` (as used by AMASS). Raises InputError with a one-line message on any file it
    cannot read as a complete, consistent body model.
    """
    if path is None:
        from mdvae_cli.body.builtin import builtin_body_model

        return builtin_body_model()
    path = Path(path)
    name = path.name
    if not path.is_file():
        what = "is a directory, not a file" if path.is_dir() else "not found"
        raise InputError(f"body model {path}: {what}")
    suffix = path.suffix.lower()
    if suffix not in (".pkl", ".pickle", ".npz"):
        raise InputError(
            f"body model {name}: unsupported file type {suffix or '(none)'!r} "
            "(expected an SMPL-family .pkl or .npz)"
        )
    with path.open("rb") as f:
        is_zip = f.read(4) == b"PK\x03\x04"
    if suffix == ".npz" or is_zip:
        if not is_zip:
            raise InputError(f"body model {name}: not an npz (zip) archive")
        return _load_npz(path)
    arrays = _read_pickle(path)
    return _assemble(name, set(arrays), lambda key: _plain_value(arrays[key], name, key))


# ---------------------------------------------------------------------------------------------
# npz


def _load_npz(path: Path) -> BodyModelData:
    name = path.name
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise InputError(f"body model {name}: not a readable npz archive ({_one_line(e)})") from e

    def fetch(key: str) -> np.ndarray:
        try:
            return archive[key]
        except ValueError as e:
            if "allow_pickle" in str(e):
                raise InputError(
                    f"body model {name}: {key!r} is stored as a pickled object "
                    "array; re-save it as a plain numeric array"
                ) from e
            raise InputError(f"body model {name}: cannot read {key!r} ({_one_line(e)})") from e
        except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise InputError(
                f"body model {name}: truncated or corrupt entry {key!r} ({_one_line(e)})"
            ) from e

    with archive:
        return _assemble(name, set(archive.files), fetch)


# ---------------------------------------------------------------------------------------------
# restricted pickle


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


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """The only plain callables a body-model pickle may name: what numpy and copyreg need.

    Python-level functions are fresh wrappers per load, so a pickle that sets attributes on
    what it loaded (BUILD) cannot alter the real ones.
    """
    import copyreg

    reconstruct = np.zeros(1).__reduce__()[0]  # built-in numpy functions: no settable state
    scalar = np.float64(0).__reduce__()[0]
    frombuffer = np.zeros(1).__reduce_ex__(5)[0]

    def rebuild(cls: type, base: type, state: Any) -> Any:
        return copyreg._reconstructor(cls, base, state)

    def newobj(cls: type, *args: Any) -> Any:
        return cls.__new__(cls, *args)

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


def _read_pickle(path: Path) -> dict[str, Any]:
    name = path.name
    try:
        with path.open("rb") as f:
            data = _RestrictedUnpickler(f, name).load()
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - any unpickling failure is a bad file
        raise InputError(
            f"body model {name}: not a readable body-model pickle "
            f"({type(e).__name__}: {_one_line(e)})"
        ) from e
    if not isinstance(data, dict):
        raise InputError(
            f"body model {name}: pickle holds a {type(data).__name__}, expected a dict"
        )
    return {str(k): v for k, v in data.items()}


def _plain_value(value: Any, label: str, key: str) -> Any:
    """Turn a pickled value into numpy: chumpy nodes evaluated, sparse matrices densified."""
    try:
        return _evaluate(value, depth=0)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - malformed state of a stand-in object
        raise InputError(
            f"body model {label}: cannot rebuild {key!r} ({type(e).__name__}: {_one_line(e)})"
        ) from e


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
    raise InputError(f"cannot evaluate chumpy object {value.qualname}")


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


# ---------------------------------------------------------------------------------------------
# arrays -> BodyModelData


def _assemble(name: str, keys: set[str], fetch: Callable[[str], Any]) -> BodyModelData:
    missing = [k for k in REQUIRED_KEYS if k not in keys]
    if missing:
        raise InputError(f"body model {name}: missing " + ", ".join(repr(k) for k in missing))

    def fail(message: str) -> InputError:
        return InputError(f"body model {name}: {message}")

    def numeric(key: str, dtype: type) -> np.ndarray:
        a = np.asarray(fetch(key))
        if a.dtype.kind not in "fiub":
            raise fail(f"{key!r} is not a numeric array (dtype {a.dtype})")
        if dtype is np.int64 and a.dtype.kind == "f" and not np.all(a == np.round(a)):
            raise fail(f"{key!r} must hold integers")
        a = a.astype(dtype)
        if dtype is np.float64 and not np.all(np.isfinite(a)):
            raise fail(f"{key!r} holds NaN or infinite values")
        return a

    style = _text(fetch, "bs_style") if "bs_style" in keys else "lbs"
    if style not in ("lbs", ""):
        raise fail(f"blend skinning style {style!r} is not supported (only 'lbs')")

    parents = _parents(numeric("kintree_table", np.int64), fail)
    J = len(parents)
    if J not in _KINDS:
        raise fail(f"kinematic tree has {J} joints; expected 24 (SMPL), 52 (SMPL-H) or 55 (SMPL-X)")
    kind, joint_names = _KINDS[J]

    v_template = numeric("v_template", np.float64)
    if v_template.ndim != 2 or v_template.shape[1] != 3 or len(v_template) == 0:
        raise fail(f"'v_template' must be (V, 3), got {v_template.shape}")
    V = len(v_template)
    J_regressor = numeric("J_regressor", np.float64)
    if J_regressor.shape != (J, V):
        raise fail(f"'J_regressor' must be ({J}, {V}), got {J_regressor.shape}")
    weights = numeric("weights", np.float64)
    if weights.shape != (V, J):
        raise fail(f"'weights' must be ({V}, {J}), got {weights.shape}")
    shapedirs = _shape_dirs(numeric("shapedirs", np.float64), V, kind, "expr_dirs" in keys, fail)
    posedirs = _pose_dirs(numeric("posedirs", np.float64), V, J, fail)
    faces = numeric("f", np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise fail(f"'f' (faces) must be (F, 3), got {faces.shape}")
    if faces.min() < 0 or faces.max() >= V:
        raise fail(f"'f' (faces) indexes vertices outside 0..{V - 1}")

    if V == SMPL_NUM_VERTICES:
        marker_ids = np.asarray(SMPL_MARKER_VERTEX_IDS, dtype=np.int64)
    else:
        from mdvae_cli.body.markers import place_markers

        smpl_joints = _smpl_joints(J_regressor @ v_template, joint_names)
        try:
            marker_ids = np.asarray(place_markers(v_template, smpl_joints), dtype=np.int64)
        except InputError as e:
            raise fail(str(e)) from e
    return BodyModelData(
        kind=kind,
        v_template=v_template,
        shapedirs=shapedirs,
        posedirs=posedirs,
        J_regressor=J_regressor,
        weights=weights,
        parents=parents,
        faces=faces,
        joint_names=tuple(joint_names),
        marker_vertex_ids=marker_ids,
        name=name,
    ).validate()


def _parents(kintree: np.ndarray, fail: Callable[[str], InputError]) -> np.ndarray:
    """(J,) parent indices from a (2, J) kintree table: row 0 parents, row 1 joint ids 0..J-1.

    The root's parent is stored as -1 or as the largest uint32, depending on who wrote the file.
    """
    if kintree.ndim != 2 or kintree.shape[0] != 2 or kintree.shape[1] == 0:
        raise fail(f"'kintree_table' must be (2, J), got {kintree.shape}")
    J = kintree.shape[1]
    if not np.array_equal(kintree[1], np.arange(J)):
        raise fail("'kintree_table' row 1 must number the joints 0..J-1 in order")
    parents = kintree[0].copy()
    if 0 <= parents[0] < J:
        raise fail("'kintree_table' must start with the root joint (no parent)")
    parents[0] = -1
    if np.any((parents[1:] < 0) | (parents[1:] >= np.arange(1, J))):
        raise fail("'kintree_table' must list every joint after its parent")
    return parents


def _shape_dirs(
    dirs: np.ndarray, V: int, kind: str, separate_expr: bool, fail: Callable[[str], InputError]
) -> np.ndarray:
    """(V, 3, S) body-shape directions; SMPL-X expression directions dropped.

    SMPL-X files store 300 shape + 100 expression columns (v1.1) or 10 + 10 (v1.0) in one
    ``shapedirs`` unless expressions come separately as ``expr_dirs``.
    """
    if dirs.ndim == 2 and dirs.shape[0] == 3 * V:
        dirs = dirs.reshape(V, 3, -1)
    if dirs.ndim != 3 or dirs.shape[:2] != (V, 3) or dirs.shape[2] == 0:
        raise fail(f"'shapedirs' must be ({V}, 3, S), got {dirs.shape}")
    S = dirs.shape[2]
    if kind == "smplx" and not separate_expr:
        S = 300 if S >= 400 else 10 if S == 20 else S
    return np.ascontiguousarray(dirs[:, :, :S])


def _pose_dirs(dirs: np.ndarray, V: int, J: int, fail: Callable[[str], InputError]) -> np.ndarray:
    """(V, 3, P) pose-corrective directions, P = 9 (J - 1), from (V, 3, P) or flat layouts.

    Flat (P, 3V) is how torch-side SMPL code keeps them (column = 3 v + axis); (3V, P) is the
    3-d layout with its first two axes merged.
    """
    P = 9 * (J - 1)
    if dirs.shape == (P, 3 * V):
        return np.ascontiguousarray(dirs.reshape(P, V, 3).transpose(1, 2, 0))
    if dirs.shape == (3 * V, P):
        return dirs.reshape(V, 3, P)
    if dirs.shape == (V, 3, P):
        return dirs
    raise fail(f"'posedirs' must be ({V}, 3, {P}) or ({P}, {3 * V}), got {dirs.shape}")


def _smpl_joints(rest_joints: np.ndarray, joint_names: tuple[str, ...]) -> np.ndarray:
    """(24, 3) joints in SMPL order from any SMPL-family rest pose.

    SMPL-H / SMPL-X have no single 'hand' joint; the middle finger's base stands in for it.
    """
    if len(joint_names) == len(SMPL_JOINT_NAMES):
        return rest_joints[: len(SMPL_JOINT_NAMES)]
    hands = [joint_names.index("left_middle1"), joint_names.index("right_middle1")]
    return np.concatenate([rest_joints[:NUM_BODY_JOINTS], rest_joints[hands]], axis=0)


def _text(fetch: Callable[[str], Any], key: str) -> str:
    """A string stored as str, bytes or a 0-d numpy string array; '' if unreadable."""
    try:
        value = fetch(key)
    except InputError:  # e.g. an npz string saved as a pickled object: not worth failing for
        return ""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("latin1")
    return str(value).strip().lower()


def _one_line(e: BaseException) -> str:
    lines = str(e).strip().splitlines()
    return lines[0] if lines else type(e).__name__
