"""Small files for the bad-input suite: a good file of every kind each reader takes, and the
raw pieces (npz members, npy headers, pickles) that bad ones are made of.

Each good file is tiny (a few frames, a few joints) and is checked to be accepted by its
commands (``test_bad_input.py::test_the_good_files_are_accepted``), so that every bad case
differs from an accepted file by its one defect.
"""

from __future__ import annotations

import gzip
import io
import os
import pickle
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np
import torch

from tests.conftest import make_tiny_body, motion_arrays

#: frames of the good motion files (enough for every command, small enough to be fast)
FRAMES = 8


# --- npz ---------------------------------------------------------------------------------------


def npy_bytes(array: np.ndarray) -> bytes:
    """``array`` as the bytes of a .npy file (object arrays pickled, as np.save does)."""
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asanyarray(array), allow_pickle=True)
    return buf.getvalue()


def npy_claiming(shape: tuple[int, ...], descr: str = "<f8", data: bytes = b"\0" * 64) -> bytes:
    """A .npy header that claims ``shape`` of ``descr``, followed by only ``data``."""
    header = repr({"descr": descr, "fortran_order": False, "shape": tuple(shape)}).encode()
    header += b" " * (-(len(header) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + data


def npz_bytes(members, compress: bool = False) -> bytes:
    """A zip archive holding each member (a dict, or (name, value) pairs: a name may come
    twice) under exactly the name given (``.npy`` is not added: member names with paths or no
    suffix are possible). Arrays are written as .npy, bytes as they are."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    pairs = members.items() if isinstance(members, dict) else members
    with warnings.catch_warnings(), zipfile.ZipFile(buf, "w", method) as zf:
        warnings.simplefilter("ignore")  # a duplicate name is what some cases are made of
        for name, value in pairs:
            raw = value if isinstance(value, bytes) else npy_bytes(value)
            zf.writestr(zipfile.ZipInfo(name), raw, compress_type=method)
    return buf.getvalue()


def motion_members(**changes) -> dict[str, bytes | np.ndarray]:
    """The members (``key.npy``) of a good motion file, with ``changes`` applied: an array or
    raw bytes replaces (or adds) a key, None removes it."""
    members: dict[str, bytes | np.ndarray] = {
        f"{k}.npy": v for k, v in motion_arrays(T=FRAMES, width=66, num_betas=10).items()
    }
    for key, value in changes.items():
        members.pop(f"{key}.npy", None)
        if value is not None:
            members[f"{key}.npy"] = value if isinstance(value, bytes) else np.asanyarray(value)
    return members


def good_motion() -> bytes:
    return npz_bytes(motion_members())


# --- pickles ------------------------------------------------------------------------------------


class Payload:
    """Pickles to a call that creates ``marker`` when unpickled (os.system or open)."""

    def __init__(self, marker: Path, via: str = "system"):
        self.marker, self.via = Path(marker), via

    def __reduce__(self):
        if self.via == "open":
            return (open, (str(self.marker), "w"))
        return (os.system, (f"touch '{self.marker}'",))


class ForeignObject:
    """Pickles as an instance of ``module.name`` (e.g. a scipy.sparse matrix) with ``state``,
    without that library: see :func:`pickled`."""

    def __init__(self, module: str, name: str, state: dict):
        self.module, self.name, self.state = module, name, state

    def __reduce__(self):
        return (_Global(self.module, self.name), (), self.state)


class _Global:
    """A reference to ``module.name`` that pickles as that name (never called here)."""

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name

    def __call__(self, *args):
        raise TypeError("a stand-in for a pickled class")


class HugeArray:
    """Unpickles as ``numpy.ndarray((10**12,))``: a pickle that asks for 8 TB."""

    def __reduce__(self):
        return (np.ndarray, ((10**12,),))


class _Pickler(pickle._Pickler):
    """Writes :class:`_Global` references as the names they hold."""

    def save_global(self, obj, name=None):
        if isinstance(obj, _Global):
            self.write(pickle.GLOBAL + f"{obj.module}\n{obj.name}\n".encode())
            self.memoize(obj)
        else:
            super().save_global(obj, name)

    dispatch = dict(pickle._Pickler.dispatch)
    dispatch[_Global] = save_global


def pickled(obj, protocol: int = 2) -> bytes:
    buf = io.BytesIO()
    _Pickler(buf, protocol=protocol).dump(obj)
    return buf.getvalue()


# --- body models --------------------------------------------------------------------------------


def body_arrays() -> dict[str, np.ndarray]:
    """The arrays of a small valid SMPL-layout body model (24 joints, 192 vertices)."""
    body = make_tiny_body()
    parents = body.parents.copy()
    parents[0] = -1
    return {
        "v_template": body.v_template,
        "shapedirs": body.shapedirs,
        "posedirs": body.posedirs,
        "J_regressor": body.J_regressor,
        "weights": body.weights,
        "kintree_table": np.stack([parents, np.arange(len(parents))]),
        "f": body.faces.astype(np.uint32),
    }


def body_members(**changes) -> dict[str, bytes | np.ndarray]:
    members: dict[str, bytes | np.ndarray] = {f"{k}.npy": v for k, v in body_arrays().items()}
    for key, value in changes.items():
        members.pop(f"{key}.npy", None)
        if value is not None:
            members[f"{key}.npy"] = value if isinstance(value, bytes) else np.asanyarray(value)
    return members


def body_pickle(**changes) -> bytes:
    """A body model as a pickled dict (as SMPL's .pkl files are), with ``changes`` applied."""
    data: dict = body_arrays()
    for key, value in changes.items():
        data.pop(key, None)
        if value is not None:
            data[key] = value
    return pickled(data)


# --- BVH ----------------------------------------------------------------------------------------

#: name, parent, offset (cm, y up, facing +z)
_BVH_RIG = [
    ("Hips", None, (0, 95, 0)),
    ("Spine", "Hips", (0, 10, 0)),
    ("Spine1", "Spine", (0, 15, 0)),
    ("Neck", "Spine1", (0, 25, 0)),
    ("Head", "Neck", (0, 10, 0)),
    ("LeftShoulder", "Spine1", (5, 20, 0)),
    ("LeftArm", "LeftShoulder", (12, 0, 0)),
    ("LeftForeArm", "LeftArm", (28, 0, 0)),
    ("LeftHand", "LeftForeArm", (25, 0, 0)),
    ("RightShoulder", "Spine1", (-5, 20, 0)),
    ("RightArm", "RightShoulder", (-12, 0, 0)),
    ("RightForeArm", "RightArm", (-28, 0, 0)),
    ("RightHand", "RightForeArm", (-25, 0, 0)),
    ("LeftUpLeg", "Hips", (9, -6, 0)),
    ("LeftLeg", "LeftUpLeg", (0, -42, 0)),
    ("LeftFoot", "LeftLeg", (0, -42, 0)),
    ("LeftToeBase", "LeftFoot", (0, -6, 12)),
    ("RightUpLeg", "Hips", (-9, -6, 0)),
    ("RightLeg", "RightUpLeg", (0, -42, 0)),
    ("RightFoot", "RightLeg", (0, -42, 0)),
    ("RightToeBase", "RightFoot", (0, -6, 12)),
]


def bvh_hierarchy(rig=_BVH_RIG) -> tuple[str, int]:
    """The HIERARCHY text of ``rig`` and its channel count (6 on the root, 3 elsewhere)."""
    kids = {r[0]: [k for k in rig if k[1] == r[0]] for r in rig}
    lines = ["HIERARCHY"]

    def block(r, depth):
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if r[1] is None else 'JOINT'} {r[0]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {' '.join(f'{v:g}' for v in r[2])}")
        pos = "Xposition Yposition Zposition " if r[1] is None else ""
        lines.append(
            f"{pad}  CHANNELS {6 if r[1] is None else 3} {pos}Zrotation Xrotation Yrotation"
        )
        for k in kids[r[0]]:
            block(k, depth + 1)
        if not kids[r[0]]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 5 0", f"{pad}  }}"])
        lines.append(pad + "}")

    block(rig[0], 0)
    return "\n".join(lines) + "\n", 3 * len(rig) + 3


def bvh_text(frames: int = FRAMES, rows: list[str] | None = None) -> str:
    """A good BVH take: a humanoid rig (Mixamo-style names), a small swing at 30 Hz."""
    hierarchy, channels = bvh_hierarchy()
    if rows is None:
        rows = []
        for f in range(frames):
            values = np.zeros(channels)
            values[:3] = (0.0, 95.0, 3.0 * f)  # root position, walking along +z
            values[3:] = 5.0 * np.sin(0.3 * f + np.arange(channels - 3))
            rows.append(" ".join(f"{v:.4f}" for v in values))
    return (
        hierarchy + f"MOTION\nFrames: {len(rows)}\nFrame Time: 0.0333333\n" + "\n".join(rows) + "\n"
    )


def deep_bvh(depth: int) -> str:
    """A BVH whose hierarchy is a chain ``depth`` joints deep, with one frame."""
    lines = ["HIERARCHY"]
    for i in range(depth):
        lines += [f"{'ROOT' if i == 0 else 'JOINT'} J{i}", "{", "OFFSET 0 1 0",
                  "CHANNELS 3 Zrotation Xrotation Yrotation"]  # fmt: skip
    lines += ["}"] * depth
    return "\n".join(lines) + f"\nMOTION\nFrames: 1\nFrame Time: 0.0333333\n{'0 ' * 3 * depth}\n"


# --- ASF/AMC ------------------------------------------------------------------------------------

#: name, parent, direction, length (inches, as CMU), dofs
_ASF_BONES = [
    ("lhipjoint", "root", (1, -1, 0), 3.0, ""),
    ("lfemur", "lhipjoint", (0, -1, 0), 7.0, "rx ry rz"),
    ("ltibia", "lfemur", (0, -1, 0), 7.0, "rx"),
    ("lfoot", "ltibia", (0, 0, 1), 2.5, "rx rz"),
    ("rhipjoint", "root", (-1, -1, 0), 3.0, ""),
    ("rfemur", "rhipjoint", (0, -1, 0), 7.0, "rx ry rz"),
    ("rtibia", "rfemur", (0, -1, 0), 7.0, "rx"),
    ("rfoot", "rtibia", (0, 0, 1), 2.5, "rx rz"),
    ("lowerback", "root", (0, 1, 0), 4.0, "rx ry rz"),
    ("thorax", "lowerback", (0, 1, 0), 6.0, "rx ry rz"),
    ("lowerneck", "thorax", (0, 1, 0), 2.0, "rx ry rz"),
    ("head", "lowerneck", (0, 1, 0), 3.0, "rx ry rz"),
    ("lclavicle", "thorax", (1, 0.2, 0), 3.0, "ry rz"),
    ("lhumerus", "lclavicle", (1, 0, 0), 5.0, "rx ry rz"),
    ("lradius", "lhumerus", (1, 0, 0), 4.0, "rx"),
    ("lhand", "lradius", (1, 0, 0), 1.5, "rx rz"),
    ("rclavicle", "thorax", (-1, 0.2, 0), 3.0, "ry rz"),
    ("rhumerus", "rclavicle", (-1, 0, 0), 5.0, "rx ry rz"),
    ("rradius", "rhumerus", (-1, 0, 0), 4.0, "rx"),
    ("rhand", "rradius", (-1, 0, 0), 1.5, "rx rz"),
]


def asf_text(bones=_ASF_BONES) -> str:
    """A good Acclaim skeleton in CMU's units (``length 0.45``) and bone names."""
    lines = [":version 1.10", ":name test", ":units", "  mass 1.0", "  length 0.45",
             "  angle deg", ":documentation", "  generated for tests", ":root",
             "   order TX TY TZ RX RY RZ", "   axis XYZ", "   position 0 0 0",
             "   orientation 0 0 0", ":bonedata"]  # fmt: skip
    for i, (name, _, direction, length, dofs) in enumerate(bones, start=1):
        lines += ["  begin", f"     id {i}", f"     name {name}",
                  f"     direction {' '.join(f'{v:g}' for v in direction)}",
                  f"     length {length:g}", "     axis 0 0 0 XYZ"]  # fmt: skip
        if dofs:
            lines.append(f"    dof {dofs}")
        lines.append("  end")
    lines += [":hierarchy", "  begin"]
    parents: dict[str, list[str]] = {}
    for name, parent, *_ in bones:
        parents.setdefault(parent, []).append(name)
    lines += [f"    {p} {' '.join(kids)}" for p, kids in parents.items()]
    lines += ["  end"]
    return "\n".join(lines) + "\n"


def amc_text(frames: int = FRAMES, bones=_ASF_BONES) -> str:
    """A good AMC motion for :func:`asf_text` (degrees, a small swing)."""
    lines = ["#!OML:ASF test.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for f in range(frames):
        lines.append(str(f + 1))
        lines.append(f"root 0 17 {0.5 * f:g} 0 0 0")
        for name, _, _, _, dofs in bones:
            if dofs:
                values = [f"{5.0 * np.sin(0.3 * f + k):.3f}" for k in range(len(dofs.split()))]
                lines.append(f"{name} {' '.join(values)}")
    return "\n".join(lines) + "\n"


def gz(data: bytes | str) -> bytes:
    return gzip.compress(data.encode() if isinstance(data, str) else data, mtime=0)


# --- checkpoints --------------------------------------------------------------------------------

WEIGHTS = Path(__file__).resolve().parents[2] / "mdvae_cli" / "weights"


def checkpoint_with(
    case: Path,
    weights: bytes | None,
    meta: str | None,
    kind: str = "denoiser",
    drop: int = 0,
    change=None,
) -> bytes:
    """A checkpoint ``case/in/bad.npz`` + ``bad.json``: the shipped ``kind`` checkpoint with
    its weights' bytes or its metadata's text replaced (None keeps the shipped one) and its
    first ``drop`` tensors left out (``change``: a function that replaces the first one).
    Writes the .json, returns the .npz bytes."""
    (case / "in").mkdir(exist_ok=True)
    shipped = WEIGHTS / f"{kind}.npz"
    if meta is None:
        meta = shipped.with_suffix(".json").read_text()
    (case / "in" / "bad.json").write_text(meta)
    if weights is not None:
        return weights
    with np.load(shipped) as npz:
        arrays = {f"{k}.npy": npz[k] for k in npz.files[drop:]}
    if change is not None:  # change(first weight) -> its replacement
        first = next(iter(arrays))
        arrays[first] = change(arrays[first])
    return npz_bytes(arrays)


# --- video pipelines' outputs -------------------------------------------------------------------


def hybrik_result(frames: int = 12) -> dict:
    """The keys of HybrIK's res.pk for a small upright clip (tests/video_files.py)."""
    from tests import video_files

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "res.pk"
        video_files.write_hybrik(path, video_files.clip(frames, seed=5))
        return pickle.loads(path.read_bytes())


def wham_bytes(frames: int = 12) -> bytes:
    """A WHAM output (joblib stream) of a small clip."""
    from tests import video_files

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "wham_output.pkl"
        video_files.write_wham(path, {0: (video_files.clip(frames, seed=6), None)})
        return path.read_bytes()


def torch_bytes(obj) -> bytes:
    """``obj`` as torch.save writes it (a zip archive holding data.pkl)."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()
