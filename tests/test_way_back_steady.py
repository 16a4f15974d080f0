"""The way back does not write the retarget's own jitter into a cleaned 120 Hz take: the
retargeted pelvis misses its target by a little each frame, and on a noisy take that miss and
the retargeted pelvis's frame jitter with the noise of the joints around them. Before, the
root's position channels of a take whose root was never noisy came back shaking (a generated
BVH: root acceleration 1.5 -> 48 m/s^2; a generated AMC: 1.9 -> 68)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner
from test_amc_out import write_take_files
from test_bvh_out import write_rig

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.asfamc import load_amc
from mdvae_cli.formats.bvh import load_bvh


def _acc(x: np.ndarray, fps: float) -> float:
    """Mean acceleration of points (T, ..., 3), per second squared."""
    return float(np.linalg.norm(np.diff(x, 2, axis=0), axis=-1).mean() * fps**2)


def _noisy_then_clean(path: Path, out: Path) -> Path:
    noisy = path.with_name("noisy" + path.suffix)
    for args in (["add-noise", "--sigma", "0.1", "--seed", "0", path, "-o", noisy],
                 ["denoise", noisy, "-o", out]):  # fmt: skip
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    return noisy


def test_a_cleaned_120hz_bvh_keeps_its_roots_steady_course(tmp_path):
    path = write_rig(tmp_path / "take.bvh", T=240, fps=120.0)
    noisy = _noisy_then_clean(path, tmp_path / "clean.bvh")
    take, shaken, clean = (load_bvh(p) for p in (path, noisy, tmp_path / "clean.bvh"))
    np.testing.assert_allclose(shaken.root_positions, take.root_positions, atol=1e-5)
    acc_in, acc_out = (_acc(m.root_positions, 120.0) for m in (take, clean))
    assert acc_out < 8.0 * acc_in, (acc_in, acc_out)  # before: 32 times
    (_, P0), (_, P1), (_, Pn) = (m.forward_kinematics() for m in (take, clean, shaken))
    err = [np.linalg.norm(P - P0, axis=-1).mean() for P in (Pn, P1)]
    assert err[1] < 0.35 * err[0], err


def test_a_cleaned_120hz_amc_keeps_its_roots_and_lowerbacks_course(tmp_path):
    path, asf = write_take_files(tmp_path / "in")
    noisy = _noisy_then_clean(path, tmp_path / "out" / "clean.amc")
    take, shaken, clean = (load_amc(p, asf) for p in (path, noisy, tmp_path / "out" / "clean.amc"))
    acc_in, acc_out = (_acc(m.root_positions, take.fps) for m in (take, clean))
    assert acc_out < 2.5 * acc_in, (acc_in, acc_out)  # before: 36 times
    (_, P0), (_, P1), (_, Pn) = (m.forward_kinematics() for m in (take, clean, shaken))
    rel = [_acc(P - P[:, :1], take.fps) for P in (P0, P1)]
    assert rel[1] < 10.0 * rel[0], rel  # the body about its root (before: 12 times)
    err = [np.linalg.norm(P - P0, axis=-1).mean() for P in (Pn, P1)]
    assert err[1] < 0.25 * err[0], err
