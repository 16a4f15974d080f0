"""HybrIK's other arrays in the rows a hole filled (``formats.hybrik_holes``): the joints placed
by the filled pose, the network's other outputs interpolated; before, every one of them stayed
NaN in a filled row (the pose, shape and translations alone were written)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.hybrik_holes import (
    PARENTS_29,
    chained_joints,
    hybrik_rows_filled,
    interpolated_rows,
)
from mdvae_cli.geometry.kinematics import world_rotations
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "video" / "hybrik"
SMPL = PARENTS_29[:24]  # SMPL's own 24 joints
HOLE = list(range(60, 66))  # rows 60-65 NaN in every float array


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _chain(local: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Joints (R, 29, 3) of the 29-joint chain: local rotations (R, 24, 3, 3), bones (29, 3)
    in the parent's frame, the root at 0."""
    G = world_rotations(local, SMPL)
    x = np.zeros((len(local), 29, 3))
    for j in range(1, 29):
        p = PARENTS_29[j]
        x[:, j] = x[:, p] + np.einsum("rij,j->ri", G[:, p], bones[j])
    return x


def test_chained_joints_are_the_chain_of_the_filled_pose():
    rng = np.random.default_rng(0)
    R = 30
    local = rotvec_to_rotmat(rng.normal(0, 0.4, (R, 24, 3)))
    bones = rng.normal(0, 0.1, (29, 3))
    truth = _chain(local, bones)
    x = truth.copy()
    x[10:14] = np.nan
    old = world_rotations(local, SMPL)
    old[10:14] = np.nan  # the file's pose is lost there too
    new = world_rotations(local, SMPL)  # the pose filled in (here: the true one)
    out = chained_joints(x, PARENTS_29, old, new)
    assert np.abs(out - truth).max() < 1e-12
    moved = world_rotations(rotvec_to_rotmat(rng.normal(0, 0.4, (R, 24, 3))), SMPL)
    out = chained_joints(x, PARENTS_29, old, moved)  # another filled pose: its own chain
    G = moved[10:14]
    for j in range(1, 29):
        p = PARENTS_29[j]
        got = np.einsum("rji,rj->ri", G[:, p], out[10:14, j] - out[10:14, p])
        assert np.abs(got - bones[j]).max() < 1e-12
    assert np.array_equal(out[:10], truth[:10]) and np.array_equal(out[14:], truth[14:])


def test_interpolated_rows_between_the_rows_beside_and_held_at_the_ends():
    a = np.array([[0.0, 1.0], [np.nan, np.nan], [np.nan, 5.0], [3.0, 7.0], [np.nan, 0.0]])
    out = interpolated_rows(a.astype(np.float32))
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [[0, 1], [1, 3], [2, 5], [3, 7], [3, 7]])
    assert np.isnan(interpolated_rows(np.full((3, 2), np.nan))).all()  # nothing to go on


@pytest.mark.skipif(not (REAL / "res.pk").is_file(), reason="the shared real files are not here")
def test_real_hybrik_file_rows_filled_whole(tmp_path):
    orig = load_data(REAL / "res.pk")
    holed = {k: np.array(v, copy=True) for k, v in orig.items()}
    for v in holed.values():
        if v.dtype.kind == "f":
            v[HOLE] = np.nan
    src = tmp_path / "res.pk"
    write_data(holed, src, "pickle")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pk")
    assert code == 0, err
    assert "pred_scores, pred_camera, pred_phi, bbox in the rows filled" in err
    out = load_data(tmp_path / "clean.pk")
    keep = np.setdiff1d(np.arange(len(orig["pred_thetas"])), HOLE)
    # mean |filled - the file's own values before they were blanked|, in each array's units
    # (joints: m / 2.2; bbox: pixels); measured 0.0018, 0.0020, 0.0016, 0.0038, 0.0020,
    # 0.0049, 0.021, 2.5
    limits = {"pred_xyz_24_struct": 0.004, "pred_xyz_29": 0.004, "pred_xyz_17": 0.004,
              "pred_uvd": 0.006, "pred_scores": 0.004, "pred_camera": 0.01, "pred_phi": 0.04,
              "bbox": 5.0}  # fmt: skip
    for k, limit in limits.items():
        got = np.asarray(out[k], np.float64)
        assert out[k].dtype == orig[k].dtype and np.isfinite(got).all(), k
        assert np.abs(got[HOLE] - np.asarray(orig[k], np.float64)[HOLE]).mean() < limit, k
        assert np.array_equal(out[k][keep], orig[k][keep]), k  # the rows it holds: as they came
    # the struct joints of a filled row: the chain of the filled pose, on the file's bones
    R = len(out["pred_thetas"])
    G = world_rotations(np.asarray(out["pred_thetas"], np.float64).reshape(R, 24, 3, 3), SMPL)
    G0 = world_rotations(np.asarray(orig["pred_thetas"], np.float64).reshape(R, 24, 3, 3), SMPL)
    x = np.asarray(out["pred_xyz_24_struct"], np.float64).reshape(R, 24, 3)
    x0 = np.asarray(orig["pred_xyz_24_struct"], np.float64).reshape(R, 24, 3)
    for j in range(1, 24):
        p = PARENTS_29[j]
        bone = np.einsum("rji,rj->ri", G[HOLE, p], x[HOLE, j] - x[HOLE, p])
        beside = [G0[r, p].T @ (x0[r, j] - x0[r, p]) for r in (HOLE[0] - 1, HOLE[-1] + 1)]
        assert np.abs(bone - np.mean(beside, axis=0)).max() < 0.001, j  # measured: 0.00015
    code, _, err = run("denoise", src, "-o", tmp_path / "off.pk", "--fill", "off")
    assert code == 0, err
    off = load_data(tmp_path / "off.pk")
    for k in limits:  # --fill off: the holes as they came
        assert np.isnan(np.asarray(off[k], np.float64)[HOLE]).all(), k


def test_without_struct_joints_the_h36m_joints_are_interpolated_and_an_all_nan_array_stays():
    R = 8
    thetas = np.tile(np.eye(3), (R, 24, 1, 1)).reshape(R, 216).astype(np.float32)
    line = np.linspace(0, 1, R)[:, None, None] * np.ones((R, 17, 3))
    data = {"pred_thetas": thetas, "pred_xyz_17": line.astype(np.float32),
            "pred_scores": np.full((R, 29), np.nan, np.float32)}  # fmt: skip
    data["pred_xyz_17"][3:5] = np.nan
    old = thetas.copy()
    old[3:5] = np.nan
    notes = hybrik_rows_filled(data, old)
    np.testing.assert_allclose(data["pred_xyz_17"], line, atol=1e-6)
    assert np.isnan(data["pred_scores"]).all()  # no finite row: nothing to go on
    assert notes and notes[0].startswith("pred_xyz_17 in the rows filled")
