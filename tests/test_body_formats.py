"""Body-model file loaders on small synthetic files in each format.

Real SMPL-family files are licensed and never enter the repo, so every file here is built in
``tmp_path``: SMPL pickles that genuinely reference ``chumpy`` and ``scipy.sparse`` classes
(through stand-in modules that exist only while pickling), SMPL-H / SMPL-X npz archives, and
broken files. Loaded arrays must equal what was written (exactly, float64).
"""

from __future__ import annotations

import contextlib
import pickle
import struct
import sys
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from mdvae_cli.body.data import SMPL_MARKER_VERTEX_IDS, SMPL_PARENTS
from mdvae_cli.body.formats import SMPLH_JOINT_NAMES, SMPLX_JOINT_NAMES, load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError

try:  # written alongside this module; the tests below stub it unless they ask for it
    import mdvae_cli.body.markers as real_markers
except ImportError:  # pragma: no cover
    real_markers = None

V = 40  # vertices of the synthetic meshes
ROOT_PARENT = np.iinfo(np.uint32).max  # how SMPL's own files mark the root


def hand_parents(wrist: int, first: int) -> list[int]:
    """5 fingers x 3 joints hanging off ``wrist``, numbered from ``first``."""
    out = []
    for finger in range(5):
        base = first + 3 * finger
        out += [wrist, base, base + 1]
    return out


def tree(J: int) -> list[int]:
    body = list(SMPL_PARENTS[:22])
    if J == 24:
        return list(SMPL_PARENTS)
    if J == 52:
        return body + hand_parents(20, 22) + hand_parents(21, 37)
    assert J == 55
    return body + [15, 15, 15] + hand_parents(20, 25) + hand_parents(21, 40)


def synthetic(J: int, S: int = 10, seed: int = 0, root: int = ROOT_PARENT) -> dict:
    """Arrays of a valid SMPL-family model with V vertices and J joints, in the file layout."""
    rng = np.random.default_rng(seed)
    P = 9 * (J - 1)
    regressor = np.zeros((J, V))
    for j in range(J):  # a few vertices per joint, like SMPL's sparse regressor
        cols = rng.choice(V, size=4, replace=False)
        regressor[j, cols] = rng.dirichlet(np.ones(4))
    weights = rng.dirichlet(np.ones(J) * 0.3, size=V)
    parents = tree(J)
    return {
        "v_template": rng.normal(size=(V, 3)) * 0.3,
        "shapedirs": rng.normal(size=(V, 3, S)) * 0.01,
        "posedirs": rng.normal(size=(V, 3, P)) * 0.01,
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.array([[root] + parents[1:], list(range(J))], dtype=np.int64),
        "f": rng.integers(0, V, size=(70, 3)).astype(np.uint32),
    }


@pytest.fixture(autouse=True)
def stub_markers(monkeypatch):
    """Marker placement belongs to body/markers.py; here a stub that records its inputs."""
    calls = []

    def place_markers(vertices, joints):
        calls.append((np.array(vertices), np.array(joints)))
        return np.arange(43, dtype=np.int64) % len(vertices)

    module = types.ModuleType("mdvae_cli.body.markers")
    module.place_markers = place_markers
    monkeypatch.setitem(sys.modules, "mdvae_cli.body.markers", module)
    return calls


# --- stand-ins for chumpy and scipy, present only while pickling ---------------------------


class Ch:
    """Pickles like ``chumpy.ch.Ch``: its ``__dict__`` minus the weak-ref caches."""

    def __init__(self, x):
        self.x = np.asarray(x)
        self._dirty_vars = {"x"}
        self._itr = None
        self._depends_on_deps = {}
        self._make_dense = False
        self._make_sparse = False
        self._parents = object()  # unpicklable in chumpy (a WeakKeyDictionary)
        self._cache = {"r": None}

    def __getstate__(self):
        state = dict(self.__dict__)
        del state["_parents"], state["_cache"]
        return state


class Select(Ch):
    """Pickles like ``chumpy.reordering.Select``: ``a.ravel()[idxs].reshape(preferred_shape)``."""

    def __init__(self, a, idxs, preferred_shape):
        super().__init__(0.0)
        del self.x
        self.a, self.idxs, self.preferred_shape = a, idxs, preferred_shape


class CscMatrix:
    """Pickles like ``scipy.sparse.csc_matrix`` (its ``__dict__``), built with numpy."""

    def __init__(self, dense):
        rows, cols = np.nonzero(dense.T)  # column-major order: (col, row) pairs
        self._shape = dense.shape
        self.maxprint = 50
        self.indices = cols.astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=dense.shape[1]))])
        self.indptr = self.indptr.astype(np.int32)
        self.data = dense.T[rows, cols]


@contextlib.contextmanager
def fake_libraries(sparse_module: str = "scipy.sparse._csc"):
    """Install ``chumpy`` and ``scipy`` modules holding the stand-ins; restore sys.modules after."""
    classes = {"chumpy.ch": [Ch], "chumpy.reordering": [Select], sparse_module: [CscMatrix]}
    names = {Ch: "Ch", Select: "Select", CscMatrix: "csc_matrix"}
    wanted = set()
    for module in classes:
        parts = module.split(".")
        wanted |= {".".join(parts[: i + 1]) for i in range(len(parts))}
    saved = {name: sys.modules.get(name) for name in wanted}
    saved_names = {cls: (cls.__module__, cls.__qualname__) for cls in names}
    try:
        for name in wanted:
            sys.modules[name] = types.ModuleType(name)
        for module, members in classes.items():
            for cls in members:
                cls.__module__, cls.__qualname__ = module, names[cls]
                setattr(sys.modules[module], names[cls], cls)
        yield
    finally:
        for cls, (module, qualname) in saved_names.items():
            cls.__module__, cls.__qualname__ = module, qualname
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


class Py2Pickler(pickle._Pickler):
    """Writes what Python 2's cPickle wrote for SMPL: strings as byte strings, ``numpy.core``."""

    dispatch = dict(pickle._Pickler.dispatch)

    def save_py2_str(self, obj):
        data = obj.encode("latin1") if isinstance(obj, str) else obj
        if len(data) < 256:
            self.write(pickle.SHORT_BINSTRING + bytes([len(data)]) + data)
        else:
            self.write(pickle.BINSTRING + struct.pack("<i", len(data)) + data)
        self.memoize(obj)

    dispatch[str] = save_py2_str
    dispatch[bytes] = save_py2_str

    def save_global(self, obj, name=None):
        numpy_core = {
            np.zeros(1).__reduce__()[0]: "_reconstruct",
            np.float64(0).__reduce__()[0]: "scalar",
        }
        if obj in numpy_core:
            self.write(pickle.GLOBAL + f"numpy.core.multiarray\n{numpy_core[obj]}\n".encode())
            self.memoize(obj)
        else:
            super().save_global(obj, name)


def write_smpl_pkl(path: Path, arrays: dict, writer="py2", sparse_module="scipy.sparse._csc"):
    """An SMPL .pkl as distributed: chumpy shapedirs / v_template, a Select, a csc regressor."""
    P = arrays["posedirs"].shape[2]
    content = dict(arrays)
    content["shapedirs"] = Ch(arrays["shapedirs"])
    content["v_template"] = Ch(arrays["v_template"])
    flat = Ch(arrays["posedirs"].ravel()[::-1].copy())  # posedirs = reversed(flat), via Select
    content["posedirs"] = Select(flat, np.arange(flat.x.size)[::-1].copy(), (V, 3, P))
    content["J_regressor"] = CscMatrix(arrays["J_regressor"])
    content["J"] = content["J_regressor"]  # unused keys are never evaluated
    content.update(bs_type="lrotmin", bs_style="lbs", vert_sym_idxs=np.arange(V))
    with fake_libraries(sparse_module), path.open("wb") as f:
        if writer == "py2":
            Py2Pickler(f, protocol=2).dump(content)
        else:
            pickle.dump(content, f, protocol=writer)
    return path


@pytest.fixture
def without_chumpy_and_scipy(monkeypatch):
    """Make ``import chumpy`` / ``import scipy`` fail while the test runs."""
    for name in [n for n in sys.modules if n == "scipy" or n.startswith(("scipy.", "chumpy"))]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "chumpy", None)
    monkeypatch.setitem(sys.modules, "scipy", None)


def assert_equal_arrays(data, arrays):
    np.testing.assert_array_equal(data.v_template, arrays["v_template"])
    np.testing.assert_array_equal(data.J_regressor, arrays["J_regressor"])
    np.testing.assert_array_equal(data.weights, arrays["weights"])
    np.testing.assert_array_equal(data.faces, arrays["f"].astype(np.int64))
    assert data.v_template.dtype == np.float64 and data.faces.dtype == np.int64


def forward(data):
    """One posed forward pass with all joints rotated; returns the BodyOutput."""
    model = BodyModel(data, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    B, J = 2, data.num_joints

    def rotvecs(*shape):
        return torch.randn(*shape, generator=g, dtype=torch.float64) * 0.3

    out = model(
        rotvecs(B, 3),
        rotvecs(B, 21, 3),
        trans=torch.zeros(B, 3, dtype=torch.float64),
        betas=torch.ones(B, 5, dtype=torch.float64),
        pose_extra=rotvecs(B, J - 22, 3) if J > 22 else None,
        vertices=True,
    )
    assert out.vertices.shape == (B, data.num_vertices, 3)
    assert out.joints.shape == (B, 22, 3) and torch.isfinite(out.vertices).all()
    assert torch.equal(out.markers, out.vertices[:, torch.as_tensor(data.marker_vertex_ids)])
    return out


# --- SMPL .pkl ----------------------------------------------------------------------------


@pytest.mark.parametrize("writer", ["py2", 0, 2, 4, 5])
def test_smpl_pkl_loads_without_chumpy_or_scipy(tmp_path, writer, request, stub_markers):
    arrays = synthetic(24)
    path = write_smpl_pkl(tmp_path / "basicModel_f.pkl", arrays, writer)
    raw = path.read_bytes()
    for name in (b"chumpy.ch", b"Ch", b"chumpy.reordering", b"Select", b"scipy.sparse._csc",
                 b"csc_matrix"):  # fmt: skip
        assert name in raw  # the file really names the foreign classes
    if writer == "py2":  # byte strings and numpy.core, as cPickle wrote them
        assert raw.startswith(b"\x80\x02}q\x00(U\nv_template")
        assert b"numpy.core.multiarray\n_reconstruct" in raw
    request.getfixturevalue("without_chumpy_and_scipy")

    data = load_body_model(path)

    assert data.kind == "smpl" and data.name == "basicModel_f.pkl"
    assert_equal_arrays(data, arrays)
    np.testing.assert_array_equal(data.shapedirs, arrays["shapedirs"])
    np.testing.assert_array_equal(data.posedirs, arrays["posedirs"])
    assert data.parents.tolist() == list(SMPL_PARENTS)
    assert data.joint_names[0] == "pelvis" and len(data.joint_names) == 24
    (vertices, joints), = stub_markers  # fmt: skip
    np.testing.assert_allclose(joints, arrays["J_regressor"] @ arrays["v_template"])
    np.testing.assert_array_equal(data.marker_vertex_ids, np.arange(43) % V)
    forward(data)


def test_smpl_pkl_with_old_scipy_module_path(tmp_path, without_chumpy_and_scipy):
    arrays = synthetic(24, seed=1)
    path = write_smpl_pkl(tmp_path / "m.pkl", arrays, writer=0, sparse_module="scipy.sparse.csc")
    assert b"scipy.sparse.csc\ncsc_matrix" in path.read_bytes()
    np.testing.assert_array_equal(load_body_model(path).J_regressor, arrays["J_regressor"])


def test_smplh_pkl(tmp_path, without_chumpy_and_scipy):
    arrays = synthetic(52, seed=2)
    data = load_body_model(write_smpl_pkl(tmp_path / "SMPLH_female.pkl", arrays))
    assert data.kind == "smplh" and data.num_joints == 52
    assert_equal_arrays(data, arrays)


class Exploit:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


def test_pickle_with_forbidden_class_is_refused_and_not_run(tmp_path):
    marker = tmp_path / "pwned"
    content = synthetic(24)
    content["weights"] = Exploit(marker)
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps(content, protocol=2))
    with pytest.raises(InputError, match=r"refusing to load '(posix|nt|os)\.system'") as info:
        load_body_model(path)
    assert not marker.exists()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "module, name",
    [("builtins", "eval"), ("__builtin__", "getattr"), ("numpy", "load"),
     ("scipy.sparse", "load_npz"), ("chumpy.ch", "Ch.__init__"), ("subprocess", "Popen")],
)  # fmt: skip
def test_any_other_global_is_refused(tmp_path, module, name):
    path = tmp_path / "g.pkl"
    path.write_bytes(b"\x80\x02c" + f"{module}\n{name}\n".encode() + b")R.")
    with pytest.raises(InputError, match=f"refusing to load '{module}.{name}'"):
        load_body_model(path)


# --- SMPL-H / SMPL-X .npz -----------------------------------------------------------------


def test_smplh_npz_as_in_amass(tmp_path):
    arrays = synthetic(52, S=16, seed=3, root=-1)
    extra = {
        "hands_componentsl": np.zeros((45, 45)),
        "hands_meanl": np.zeros(45),
        "J": np.zeros((52, 3)),
        "bs_style": np.array("lbs"),
        "bs_type": np.array("lrotmin"),
    }
    np.savez(tmp_path / "model.npz", **arrays, **extra)

    data = load_body_model(tmp_path / "model.npz")

    assert data.kind == "smplh" and data.name == "model.npz"
    assert_equal_arrays(data, arrays)
    np.testing.assert_array_equal(data.shapedirs, arrays["shapedirs"])
    np.testing.assert_array_equal(data.posedirs, arrays["posedirs"])
    assert data.parents.tolist() == tree(52)
    assert data.joint_names == SMPLH_JOINT_NAMES
    assert data.joint_names[22] == "left_index1" and data.joint_names[51] == "right_thumb3"
    forward(data)


def test_markers_get_smpl_joints_from_hand_models(tmp_path, stub_markers):
    arrays = synthetic(52, seed=4)
    np.savez(tmp_path / "model.npz", **arrays)
    load_body_model(tmp_path / "model.npz")
    (vertices, joints), = stub_markers  # fmt: skip
    rest = arrays["J_regressor"] @ arrays["v_template"]
    assert joints.shape == (24, 3)
    np.testing.assert_allclose(joints[:22], rest[:22])
    middle1 = [SMPLH_JOINT_NAMES.index("left_middle1"), SMPLH_JOINT_NAMES.index("right_middle1")]
    np.testing.assert_allclose(joints[22:], rest[middle1])
    np.testing.assert_array_equal(vertices, arrays["v_template"])


@pytest.mark.parametrize("layout", ["flat", "merged", "3d"])
def test_smplx_npz_drops_expressions_and_reads_posedirs_layout(tmp_path, layout):
    arrays = synthetic(55, S=400, seed=5)
    P = 9 * 54
    posedirs = arrays["posedirs"]
    stored = {"flat": posedirs.reshape(V * 3, P).T, "merged": posedirs.reshape(V * 3, P),
              "3d": posedirs}[layout]  # fmt: skip
    joint2num = np.array({"pelvis": 0}, dtype=object)  # real SMPL-X npz hold pickled dicts
    np.savez(tmp_path / "SMPLX_NEUTRAL.npz", **{**arrays, "posedirs": stored},
             joint2num=joint2num, lmk_faces_idx=np.zeros(51, np.int64))  # fmt: skip

    data = load_body_model(tmp_path / "SMPLX_NEUTRAL.npz")

    assert data.kind == "smplx" and data.num_joints == 55
    assert data.joint_names == SMPLX_JOINT_NAMES and data.joint_names[22] == "jaw"
    np.testing.assert_array_equal(data.shapedirs, arrays["shapedirs"][:, :, :300])
    np.testing.assert_array_equal(data.posedirs, posedirs)
    assert_equal_arrays(data, arrays)
    forward(data)


def test_smplx_v1_0_keeps_ten_shape_directions(tmp_path):
    arrays = synthetic(55, S=20, seed=6)
    np.savez(tmp_path / "smplx.npz", **arrays)
    data = load_body_model(tmp_path / "smplx.npz")
    np.testing.assert_array_equal(data.shapedirs, arrays["shapedirs"][:, :, :10])


def test_smpl_topology_uses_standard_marker_vertices(tmp_path, stub_markers):
    rng = np.random.default_rng(7)
    n = 6890
    regressor = np.zeros((24, n))
    regressor[np.arange(24), np.arange(24) * 7] = 1.0
    arrays = {
        "v_template": rng.normal(size=(n, 3)).astype(np.float32),
        "shapedirs": np.zeros((n, 3, 2), np.float32),
        "posedirs": np.zeros((n, 3, 207), np.float32),
        "J_regressor": regressor,
        "weights": np.repeat(np.eye(24)[:1], n, axis=0),
        "kintree_table": np.array([[ROOT_PARENT, *SMPL_PARENTS[1:]], range(24)], np.uint32),
        "f": np.array([[0, 1, 2]], np.int32),
    }
    np.savez(tmp_path / "smpl.npz", **arrays)
    data = load_body_model(tmp_path / "smpl.npz")
    assert data.marker_vertex_ids.tolist() == list(SMPL_MARKER_VERTEX_IDS)
    assert not stub_markers
    forward(data)


# T-pose SMPL joints (metres; +x left, +y up, +z forward), roughly a 1.7 m adult.
TPOSE = [(0, .95, 0), (.09, .87, 0), (-.09, .87, 0), (0, 1.05, 0), (.1, .5, 0), (-.1, .5, 0),
         (0, 1.18, 0), (.1, .08, 0), (-.1, .08, 0), (0, 1.25, 0), (.1, .02, .12),
         (-.1, .02, .12), (0, 1.45, 0), (.08, 1.38, 0), (-.08, 1.38, 0), (0, 1.55, 0),
         (.18, 1.4, 0), (-.18, 1.4, 0), (.45, 1.4, 0), (-.45, 1.4, 0), (.7, 1.4, 0),
         (-.7, 1.4, 0), (.78, 1.4, 0), (-.78, 1.4, 0)]  # fmt: skip


@pytest.mark.skipif(real_markers is None, reason="mdvae_cli.body.markers not available")
def test_real_marker_placement_on_a_small_mesh(tmp_path, monkeypatch, without_chumpy_and_scipy):
    monkeypatch.setitem(sys.modules, "mdvae_cli.body.markers", real_markers)
    arrays = synthetic(24, seed=8)
    rng = np.random.default_rng(8)
    arrays["v_template"][:24] = TPOSE  # joint j sits on vertex j
    arrays["v_template"][24:] = np.asarray(TPOSE)[rng.integers(0, 24, V - 24)] + 0.05
    arrays["J_regressor"] = np.eye(24, V)
    data = load_body_model(write_smpl_pkl(tmp_path / "m.pkl", arrays))
    assert data.marker_vertex_ids.shape == (43,) and data.marker_vertex_ids.max() < V
    forward(data)


def test_marker_placement_errors_name_the_file(tmp_path, stub_markers, monkeypatch):
    def refuse(vertices, joints):
        raise InputError("marker placement: head is not above the ankles")

    monkeypatch.setattr(sys.modules["mdvae_cli.body.markers"], "place_markers", refuse)
    np.savez(tmp_path / "upside.npz", **synthetic(24))
    expect_error(tmp_path / "upside.npz", "^body model upside.npz: marker placement: head")


def test_none_loads_the_builtin_body(monkeypatch):
    sentinel = object()
    module = types.ModuleType("mdvae_cli.body.builtin")
    module.builtin_body_model = lambda: sentinel
    monkeypatch.setitem(sys.modules, "mdvae_cli.body.builtin", module)
    assert load_body_model(None) is sentinel
    assert load_body_model() is sentinel


# --- files we cannot use --------------------------------------------------------------------


def expect_error(path, pattern):
    with pytest.raises(InputError, match=pattern) as info:
        load_body_model(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith("body model ")
    return message


def test_missing_keys_are_all_named(tmp_path):
    arrays = synthetic(24)
    del arrays["weights"], arrays["kintree_table"]
    np.savez(tmp_path / "foo.npz", **arrays)
    message = expect_error(tmp_path / "foo.npz", "missing")
    assert message == "body model foo.npz: missing 'weights', 'kintree_table'"


def test_missing_keys_in_pickle(tmp_path):
    (tmp_path / "d.pkl").write_bytes(pickle.dumps({"v_template": np.zeros((3, 3))}))
    expect_error(tmp_path / "d.pkl", "missing 'shapedirs', 'posedirs', 'J_regressor'")


@pytest.mark.parametrize("suffix", [".pkl", ".npz"])
def test_garbage_and_empty_files(tmp_path, suffix):
    rng = np.random.default_rng(0)
    (tmp_path / f"junk{suffix}").write_bytes(rng.integers(0, 256, 500, dtype=np.uint8).tobytes())
    (tmp_path / f"empty{suffix}").write_bytes(b"")
    expect_error(tmp_path / f"junk{suffix}", "not")
    expect_error(tmp_path / f"empty{suffix}", "not")


@pytest.mark.parametrize("suffix", [".pkl", ".npz"])
def test_truncated_files(tmp_path, suffix):
    arrays = synthetic(24)
    path = tmp_path / f"cut{suffix}"
    if suffix == ".pkl":
        write_smpl_pkl(path, arrays)
    else:
        np.savez(path, **arrays)
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    expect_error(path, "truncated")


def test_corrupt_npz_member(tmp_path):
    path = tmp_path / "bad.npz"
    np.savez_compressed(path, **synthetic(24))
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("weights.npy")
    raw = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename) + 40
    raw[start : start + 64] = bytes(64)
    path.write_bytes(bytes(raw))
    expect_error(path, "weights")


def test_unknown_suffix_missing_path_and_directory(tmp_path):
    (tmp_path / "body.obj").write_text("v 0 0 0\n")
    expect_error(tmp_path / "body.obj", "unsupported file type '.obj'")
    expect_error(tmp_path / "nowhere.pkl", "not found")
    expect_error(tmp_path, "directory")


def test_npy_renamed_npz_and_non_dict_pickle(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros(3))
    (tmp_path / "a.npy").rename(tmp_path / "a.npz")
    expect_error(tmp_path / "a.npz", "not an npz")
    (tmp_path / "l.pkl").write_bytes(pickle.dumps([1, 2, 3]))
    expect_error(tmp_path / "l.pkl", "holds a list")


def test_object_array_of_numbers_is_read_without_running_anything(tmp_path):
    arrays = synthetic(24)
    arrays["J_regressor"] = np.array(arrays["J_regressor"], dtype=object)
    np.savez(tmp_path / "obj.npz", **arrays)  # read by the restricted unpickler (was refused)
    data = load_body_model(tmp_path / "obj.npz")
    np.testing.assert_array_equal(data.J_regressor, arrays["J_regressor"].astype(float))
    arrays["J_regressor"] = np.array([[object()]], dtype=object)
    np.savez(tmp_path / "obj.npz", **arrays)
    expect_error(tmp_path / "obj.npz", "obj.npz: 'J_regressor' is not a numeric array")


@pytest.mark.parametrize(
    "key, value, pattern",
    [
        ("posedirs", np.zeros((V, 3, 10)), "'posedirs' must be"),
        ("shapedirs", np.zeros((V, 2, 10)), "'shapedirs' must be"),
        ("weights", np.zeros((V, 23)), "'weights' must be"),
        ("J_regressor", np.zeros((24, V + 1)), "'J_regressor' must be"),
        ("v_template", np.full((V, 3), np.nan), "NaN"),
        ("f", np.array([[0, 1, V]]), "outside"),
        ("f", np.array([[0, 1, 2.5]]), "integers"),
        ("kintree_table", np.array([[-1] + list(range(29)), list(range(30))]), "30 joints"),
        ("kintree_table", np.zeros((3, 24), np.int64), r"\(2, J\)"),
        ("kintree_table", np.array([[-1, *SMPL_PARENTS[1:]], range(1, 25)]), "0..J-1"),
        ("kintree_table", np.array([[0, *SMPL_PARENTS[1:]], range(24)]), "root"),
        ("kintree_table", np.array([[-1, 0, 5, *SMPL_PARENTS[3:]], range(24)]), "after its"),
        ("bs_style", np.array("dqs"), "'dqs'"),
    ],
)
def test_inconsistent_arrays(tmp_path, key, value, pattern):
    arrays = synthetic(24)
    arrays[key] = value
    np.savez(tmp_path / "x.npz", **arrays)
    expect_error(tmp_path / "x.npz", pattern)
