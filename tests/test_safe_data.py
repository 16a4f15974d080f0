"""The restricted data unpickler (formats/safe_data.py): pickles, joblib streams, torch files and
object .npy/.npz read as numpy without running code; anything else refused in one line."""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from collections import OrderedDict, defaultdict
from pathlib import Path

import numpy as np
import pytest
import torch
from video_files import joblib_dumps

from mdvae_cli.errors import InputError
from mdvae_cli.formats.data_files import load_data, sniff

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"


def _tensors():
    base = torch.arange(24, dtype=torch.float32).reshape(4, 6)
    return {
        "f32": base,
        "f64": torch.linspace(0, 1, 5, dtype=torch.float64),
        "i64": torch.arange(7),
        "bool": torch.tensor([True, False, True]),
        "strided": base.t()[1:3],  # a non-contiguous view of a shared storage
        "scalar": torch.tensor(2.5),
        "nested": OrderedDict(a=[torch.ones(2, 3), (torch.zeros(1), "text")], b=3),
    }


def _check(loaded, reference):
    if isinstance(reference, torch.Tensor):
        assert isinstance(loaded, np.ndarray)
        np.testing.assert_array_equal(loaded, reference.numpy())
    elif isinstance(reference, dict):
        assert set(loaded) == set(reference)
        for k in reference:
            _check(loaded[k], reference[k])
    elif isinstance(reference, list | tuple):
        assert len(loaded) == len(reference)
        for a, b in zip(loaded, reference, strict=True):
            _check(a, b)
    else:
        assert loaded == reference


@pytest.mark.parametrize("zip_format", [True, False])
def test_torch_files_read_as_numpy(tmp_path, zip_format):
    path = tmp_path / "t.pt"
    torch.save(_tensors(), path, _use_new_zipfile_serialization=zip_format)
    assert sniff(path.read_bytes()) == ("zip" if zip_format else "pickle")
    _check(load_data(path), _tensors())


def test_numpy_save_of_a_dict_of_tensors(tmp_path):
    """TRAM's hps_track files: np.save of a dict of tensors (tensors pickled by value)."""
    path = tmp_path / "hps_track_0.npy"
    np.save(path, _tensors(), allow_pickle=True)
    arr = load_data(path)
    assert arr.dtype.hasobject and arr.shape == ()
    _check(arr.item(), _tensors())


def test_npz_with_object_arrays(tmp_path):
    path = tmp_path / "video_results.npz"
    np.savez(path, results={"a": np.arange(3)}, plain=np.eye(2))
    out = load_data(path)
    np.testing.assert_array_equal(out["plain"], np.eye(2))
    np.testing.assert_array_equal(out["results"].item()["a"], np.arange(3))


@pytest.mark.parametrize("compress", [False, True])
@pytest.mark.parametrize("align", [False, True])
def test_joblib_streams_with_in_stream_arrays(tmp_path, compress, align):
    tracks = defaultdict(dict)
    tracks[np.int64(0)] = {"pose": np.random.default_rng(0).normal(size=(5, 72)).astype("f4"),
                           "frame_ids": np.arange(5), "empty": np.zeros((0, 3))}  # fmt: skip
    tracks[np.int64(3)] = {"fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3))}
    path = tmp_path / "wham_output.pkl"
    path.write_bytes(joblib_dumps(tracks, compress=compress, align=align))
    out = load_data(path)
    assert type(out) is dict and list(out) == [0, 3]
    assert isinstance(list(out)[0], np.int64)
    np.testing.assert_array_equal(out[0]["pose"], tracks[np.int64(0)]["pose"])
    np.testing.assert_array_equal(out[0]["frame_ids"], np.arange(5))
    assert out[0]["empty"].shape == (0, 3)
    np.testing.assert_array_equal(out[3]["fortran"], np.arange(6.0).reshape(2, 3))


def test_plain_pickles_numpy_1_and_2_spellings(tmp_path):
    arr = np.arange(6, dtype=np.float32).reshape(2, 3)
    data = pickle.dumps({"x": arr, "n": np.float64(1.5), "s": "text"}, protocol=2)
    other = data.replace(b"numpy._core.multiarray", b"numpy.core.multiarray").replace(
        b"numpy.core.multiarray", b"numpy._core.multiarray"
    )
    for blob in (data, other):
        (tmp_path / "a.pkl").write_bytes(blob)
        out = load_data(tmp_path / "a.pkl")
        np.testing.assert_array_equal(out["x"], arr)
        assert out["n"] == 1.5 and out["s"] == "text"


class _Evil:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _evil(marker: Path) -> _Evil:
    e = _Evil()
    e.marker = marker
    return e


@pytest.mark.parametrize("container", ["pickle", "joblib", "torch", "npy", "npz"])
def test_code_in_a_pickle_is_refused_in_one_line_and_never_runs(tmp_path, container):
    marker = tmp_path / "ran"
    payload = {"pose": np.zeros(3), "x": _evil(marker)}
    path = tmp_path / f"evil.{container}"
    if container == "pickle":
        path.write_bytes(pickle.dumps(payload))
    elif container == "joblib":
        path.write_bytes(joblib_dumps(payload))
    elif container == "torch":
        buf = io.BytesIO()
        torch.save({"t": torch.zeros(2)}, buf)
        with zipfile.ZipFile(buf) as zin, zipfile.ZipFile(path, "w") as zout:
            for name in zin.namelist():
                data = zin.read(name)
                if name.endswith("data.pkl"):
                    data = pickle.dumps(payload, protocol=2)
                zout.writestr(name, data)
    elif container == "npy":
        np.save(path, payload, allow_pickle=True)
    else:
        np.savez(path, results=payload)
    with pytest.raises(InputError) as exc:
        load_data(path)
    message = str(exc.value)
    assert "\n" not in message and "refusing to load 'posix.system'" in message
    assert str(path) in message
    assert not marker.exists()


@pytest.mark.parametrize(
    "global_name", [b"builtins\neval\n", b"builtins\ngetattr\n", b"subprocess\nPopen\n"]
)
def test_other_dangerous_globals_are_refused(tmp_path, global_name):
    path = tmp_path / "g.pkl"
    path.write_bytes(b"\x80\x02c" + global_name + b"X\x01\x00\x00\x001\x85R.")
    with pytest.raises(InputError, match="refusing to load"):
        load_data(path)


@pytest.mark.parametrize(
    "blob", [b"", b"not a pickle at all", b"\x80\x04\x95", b"PK\x03\x04broken", b"\x93NUMPY\x01"]
)
def test_damaged_files_are_one_line_errors(tmp_path, blob):
    path = tmp_path / "bad.pkl"
    path.write_bytes(blob)
    with pytest.raises(InputError) as exc:
        load_data(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_a_joblib_array_larger_than_the_file_is_refused(tmp_path):
    blob = joblib_dumps({"a": np.zeros(1000)})
    path = tmp_path / "cut.pkl"
    path.write_bytes(blob[: len(blob) - 4000])  # inside the array's bytes
    with pytest.raises(InputError, match="bytes"):
        load_data(path)


@pytest.mark.parametrize(
    "name", ["video/wham/wham_output.pkl", "video/gvhmr/tennis_hmr4d_results.pt",
             "video/hybrik/res.pk", "smpl/aistpp/gWA_sFM_cAll_d27_mWA5_ch20.pkl"],
)  # fmt: skip
def test_real_pipeline_files_open(name):
    path = REAL / name
    if not path.is_file():
        pytest.skip("shared real data not present")
    data = load_data(path)
    assert isinstance(data, dict) and data
