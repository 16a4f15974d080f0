"""A video pipeline's file comes back in the pickle container it came in: a WHAM result saved
with ``joblib.dump(..., compress=3)`` stays compressed, one re-saved as a plain pickle stays
one that ``pickle.load`` opens (``VideoDocument.written_container``)."""

from __future__ import annotations

import gzip
import pickle
import zlib

import numpy as np
import pytest
import video_files as vf
from video_files import edited

from mdvae_cli.formats.data_files import pickled_container, sniff
from mdvae_cli.formats.registry import read, write

joblib = pytest.importorskip("joblib")


def _wham_dict(tmp_path):
    src = vf.write_wham(tmp_path / "made.pkl", {0: (vf.clip(24, seed=1), None)})
    return joblib.load(src)


def _round_trip(src, out):
    loaded = read(src)
    after, _ = edited(loaded.single())  # a visible edit, to see it written
    write(after, out, document=loaded.document)
    return out.read_bytes()


@pytest.mark.parametrize(
    ("compress", "container", "magic"),
    [(3, "joblib-zlib", "zlib"), (("gzip", 3), "joblib-gzip", "gzip"), (0, "joblib", "pickle")],
)
def test_a_joblib_file_comes_back_compressed_as_it_came(tmp_path, compress, container, magic):
    data = _wham_dict(tmp_path)
    src = tmp_path / "wham_output.pkl"
    joblib.dump(data, src, compress=compress)
    assert pickled_container(src.read_bytes()) == container
    written = _round_trip(src, tmp_path / "clean.pkl")
    assert sniff(written) == magic
    back = joblib.load(tmp_path / "clean.pkl")
    assert set(back[0]) == set(data[0]) - {"verts"}  # stale vertices are left out
    assert back[0]["pose"].shape == data[0]["pose"].shape
    assert not np.allclose(back[0]["pose_world"][:, 3:], data[0]["pose_world"][:, 3:])
    if compress:  # compressed as the file was: far smaller than the raw stream
        raw = zlib.decompress(written) if magic == "zlib" else gzip.decompress(written)
        assert len(written) < 0.9 * len(raw)


def test_a_wham_file_resaved_as_a_plain_pickle_stays_one(tmp_path):
    data = {k: dict(v) for k, v in _wham_dict(tmp_path).items()}
    src = tmp_path / "wham_output.pkl"
    with open(src, "wb") as fh:
        pickle.dump(data, fh)
    assert pickled_container(src.read_bytes()) == "pickle"
    written = _round_trip(src, tmp_path / "clean.pkl")
    assert b"NumpyArrayWrapper" not in written
    back = pickle.loads(written)  # no joblib needed to open it, as before
    assert back[0]["pose"].shape == data[0]["pose"].shape
    assert np.isfinite(back[0]["pose"]).all()
