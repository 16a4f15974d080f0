"""Body-model file loaders: SMPL ``.pkl``, SMPL-H / SMPL-X ``.npz`` -> :class:`BodyModelData`.

Plain numpy only: the SMPL pickles as distributed hold ``chumpy`` arrays and a ``scipy.sparse``
joint regressor, and are read without either library by the restricted unpickler of
:mod:`mdvae_cli.body.safe_pickle`, which rebuilds those objects from their pickled state and
refuses every other class.

The model kind is read from the file's kinematic tree (24 joints SMPL, 52 SMPL-H, 55 SMPL-X),
never from its name. Every failure is an :class:`InputError` with a one-line message.
"""

from __future__ import annotations

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
from mdvae_cli.body.safe_pickle import plain_value, read_pickle, unpickle_stream
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_regular
from mdvae_cli.npz_archive import NpzArchive

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
        if path.exists() and not path.is_dir():
            check_regular(path)  # a FIFO or a device, said as such (reading one would hang)
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
    arrays = read_pickle(path)
    return _assemble(name, set(arrays), lambda key: plain_value(arrays[key], name, key))


# ---------------------------------------------------------------------------------------------
# npz


#: bytes the arrays of a body-model .npz may take together (SMPL-X with 400 shape components
#: and every hand and face array: about 0.3 GB)
MAX_NPZ_BYTES = 512 << 20


def _load_npz(path: Path) -> BodyModelData:
    """Only the arrays the model needs are read, each checked before it is allocated. An
    array saved as pickled objects (``np.savez`` of an SMPL pickle's scipy.sparse
    ``J_regressor``) is read as the pickles are, nothing run."""
    name = path.name

    def fetch(key: str) -> Any:
        def unpickle(stream: Any, _where: str) -> Any:
            return unpickle_stream(stream, f"{name}: {key!r}")

        value = archive.read(key, unpickle=unpickle)
        if isinstance(value, np.ndarray) and value.dtype.hasobject:  # numbers as objects too
            value = value.item() if value.shape == () else np.array(value.tolist())
        return plain_value(value, name, key)

    with NpzArchive(path, f"body model {name}", max_total=MAX_NPZ_BYTES) as archive:
        return _assemble(name, set(archive.keys), fetch)


# ---------------------------------------------------------------------------------------------
# arrays -> BodyModelData


def _assemble(name: str, keys: set[str], fetch: Callable[[str], Any]) -> BodyModelData:
    missing = [k for k in REQUIRED_KEYS if k not in keys]
    if len(missing) == len(REQUIRED_KEYS):
        raise InputError(f"body model {name}: {_not_a_model(keys)}")
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
    _check_values(v_template, J_regressor, weights, fail)
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


#: keys of motion files (AMASS, SMPL parameter dumps, AIST++, GVHMR) given as a body model
_MOTION_KEYS = ("poses", "root_orient", "pose_body", "trans", "transl", "global_orient",
                "body_pose", "smpl_poses", "mocap_framerate", "mocap_frame_rate")  # fmt: skip


def _not_a_model(keys: set[str]) -> str:
    """Why a file holding none of a model's arrays is refused: a motion file given by mistake,
    or some other file."""
    motion = [k for k in _MOTION_KEYS if k in keys] or sorted(
        k for k in keys if k.startswith("smpl_params")
    )
    give = "give the SMPL, SMPL-H or SMPL-X model file (e.g. SMPL_NEUTRAL.pkl, model.npz)"
    if motion:
        return (
            f"a motion file (it holds {', '.join(map(repr, motion[:2]))}), not a body model; {give}"
        )
    model = ", ".join(map(repr, REQUIRED_KEYS[:3]))
    return f"not a body model (none of {model}, ... in it); {give}"


#: how far a row of a model's skinning weights or joint regressor may sum from 1: loosely
#: (SMPL's regressor was fit by non-negative least squares that favours, not forces, a sum of
#: 1), so that only a zeroed, doubled or damaged array is refused
_SUM_TOLERANCE = 0.5
#: metres a body model's rest mesh may span, loosely (centimetres give 170, millimetres 1,700)
_SPAN_M = (0.1, 10.0)


def _check_values(
    v_template: np.ndarray,
    J_regressor: np.ndarray,
    weights: np.ndarray,
    fail: Callable[[str], InputError],
) -> None:
    """Refuse arrays of the right shapes but no body's values: weights or regressor rows that
    do not sum to 1 (a damaged or zeroed array: the mesh would collapse, the joints sit at
    the origin) and a mesh in other units than metres.  (V, 3), (J, V), (V, J)"""
    for key, rows, what in (("weights", weights, "vertex"), ("J_regressor", J_regressor, "joint")):
        off = np.abs(rows.sum(axis=1) - 1.0)
        if off.max() > _SUM_TOLERANCE:
            i = int(off.argmax())
            raise fail(f"{key!r} rows must each sum to about 1; {what} {i}'s sums to "
                       f"{rows[i].sum():.3g} (the file is damaged)")  # fmt: skip
    span = float(np.ptp(v_template, axis=0).max())
    if not _SPAN_M[0] <= span <= _SPAN_M[1]:
        raise fail(f"the rest mesh spans {span:.4g} m; a body model in metres spans "
                   f"{_SPAN_M[0]:g}-{_SPAN_M[1]:g} m (is it in another unit?)")  # fmt: skip


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
