"""Holes in BVH takes (issue 32): ``--missing frozen,zeros`` names them, ``denoise`` fills them,
``--fill off`` writes the take's own frames back there."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.missing import frozen_frames, missing_channels, parse_rules
from mdvae_cli.retarget.retarget import load_source
from tests.test_bvh_out import _RIG, write_rig

FROZEN = slice(31, 50)  # LowerArm_L holds frame 30's values
ZERO = 70


def _walk_order() -> list[str]:
    kids = {r[0]: [k for k in _RIG if k[1] == r[0]] for r in _RIG}
    order: list[str] = []

    def walk(r):
        order.append(r[0])
        for k in kids[r[0]]:
            walk(k)

    walk(_RIG[0])
    return order


def _rows(path: Path) -> np.ndarray:
    lines = path.read_text().split("Frame Time:")[1].splitlines()[1:]
    return np.array([[float(v) for v in line.split()] for line in lines if line.strip()])


def holey_bvh(path: Path, T: int = 90) -> tuple[Path, int]:
    """The generated rig with LowerArm_L frozen over FROZEN and frame ZERO all zeros; and the
    first column of LowerArm_L."""
    write_rig(path, T=T)
    head, rest = path.read_text().split("Frame Time:")
    data = _rows(path)
    c = 6 + 3 * (_walk_order().index("LowerArm_L") - 1)
    data[FROZEN, c : c + 3] = data[FROZEN.start - 1, c : c + 3]
    data[ZERO] = 0.0
    body = "\n".join(" ".join(f"{v:.4f}" for v in row) for row in data)
    path.write_text(f"{head}Frame Time:{rest.splitlines()[0]}\n{body}\n")
    return path, c


def run(*args) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def test_frozen_and_zero_frames_found(tmp_path):
    path, _ = holey_bvh(tmp_path / "take.bvh")
    src = load_source(path)
    missing, found = missing_channels(src, ("frozen", "zeros"))
    arm = src.names.index("LowerArm_L")
    expect = np.zeros(90, bool)
    expect[FROZEN] = True
    expect[ZERO] = True
    assert np.array_equal(missing[:, arm], expect)
    assert missing[ZERO].all() and missing.sum() == 19 + src.num_joints
    assert found == {"zero_frames": 1, "frozen": {"LowerArm_L": 19}}
    assert not missing_channels(src, ())[0].any()
    assert missing_channels(src, ("zeros",))[0].sum() == src.num_joints


def test_holds_that_are_no_holes(tmp_path):
    """Not holes: a still take, a hold that eases out (no jump when it ends), a hold that runs
    to the end of the take, a hold one frame too short."""
    path, c = holey_bvh(tmp_path / "take.bvh")
    src = load_source(path)
    assert frozen_frames(src.fps) == 10
    arm = slice(c, c + 3)
    data = src.layout.data
    original = data.copy()
    data[FROZEN.stop :, arm] -= data[FROZEN.stop, arm] - data[FROZEN.start, arm]  # eases out
    assert not missing_channels(src, ("frozen",))[0].any()
    data[:] = original
    data[60:, arm] = data[60, arm]  # to the end
    data[20:29, arm] = data[20, arm]  # 9 frames, then a jump
    data[29, arm] += 30.0
    missing = missing_channels(src, ("frozen",))[0]
    assert np.flatnonzero(missing.any(axis=1)).tolist() == list(range(31, 50))
    data[:] = original
    data[:15, arm] = 0.0  # not found yet at the start: missing from frame 0
    data[15, arm] += 30.0
    missing = missing_channels(src, ("frozen",))[0]
    assert np.flatnonzero(missing.any(axis=1)).tolist() == [*range(15), *range(31, 50)]
    data[:] = data[0]  # nobody moves
    assert not missing_channels(src, ("frozen",))[0].any()


def test_denoise_missing_fills_and_fill_off_keeps_the_takes_frames(tmp_path):
    path, c = holey_bvh(tmp_path / "take.bvh")
    code, out, err = run("denoise", path, "-o", tmp_path / "clean.bvh", "--missing",
                         "frozen,zeros", "--json")  # fmt: skip
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert (result["filled_frames"], result["filled_joints"]) == (20, 19 + 22)
    assert "--missing: 20 frame(s) with missing joints" in err
    clean = _rows(tmp_path / "clean.bvh")
    assert np.abs(clean[ZERO]).max() > 10  # a pose, not zeros
    code, out, err = run("denoise", path, "-o", tmp_path / "off.bvh", "--missing",
                         "frozen,zeros", "--fill", "off")  # fmt: skip
    assert code == 0, err
    off, raw = _rows(tmp_path / "off.bvh"), _rows(path)
    assert np.array_equal(off[ZERO], raw[ZERO])
    assert np.allclose(off[FROZEN, c : c + 3], raw[FROZEN, c : c + 3])
    code, out, err = run("denoise", path, "-o", tmp_path / "plain.bvh", "--json")
    assert json.loads(out)["files"][0]["result"]["filled_frames"] == 0


def test_missing_rules_parsed():
    assert parse_rules("frozen, zeros,frozen") == ("frozen", "zeros")
    assert parse_rules("") == parse_rules("none") == ()
    with pytest.raises(InputError, match="unknown rule 'nan'"):
        parse_rules("frozen,nan")


def test_amc_frozen_bone_filled_and_kept_with_fill_off(tmp_path):
    from tests.test_amc_out import amc_file, asf_text, motion_values

    values = motion_values(120)
    values["lradius"][40:90] = values["lradius"][39]  # a lost marker: held for 50 frames
    (tmp_path / "gen.asf").write_text(asf_text())
    path = tmp_path / "gen_01.amc"
    path.write_text(amc_file(values))
    src = load_source(path, tmp_path / "gen.asf")
    missing, found = missing_channels(src, ("frozen",))
    assert found["frozen"] == {"lradius": 50} and missing.sum() == 50
    for fill, name in (("on", "clean.amc"), ("off", "off.amc")):
        code, out, err = run("denoise", path, "-o", tmp_path / name, "--missing", "frozen",
                             "--fill", fill, "--json")  # fmt: skip
        assert code == 0, err
        assert json.loads(out)["files"][0]["result"]["filled_frames"] == (50 if fill == "on" else 0)
    from mdvae_cli.formats.asfamc import load_amc

    clean = load_amc(tmp_path / "clean.amc", tmp_path / "gen.asf").layout.values["lradius"]
    off = load_amc(tmp_path / "off.amc", tmp_path / "gen.asf").layout.values["lradius"]
    assert np.ptp(clean[40:90]) > 0.01  # filled: it moves again
    assert np.allclose(off[40:90], values["lradius"][40:90], atol=1e-6)


def test_import_missing_marks_the_holes_in_joint_mask(tmp_path):
    path, _ = holey_bvh(tmp_path / "take.bvh")
    code, out, err = run("import", path, "-o", tmp_path / "take.npz", "--missing", "zeros",
                         "--json")  # fmt: skip
    assert code == 0, err
    assert json.loads(out)["files"][0]["result"]["missing_frames"] == 1
    mask = np.load(tmp_path / "take.npz")["joint_mask"]
    assert (~mask).all(axis=1).sum() == 1 and mask.sum() == 89 * 22
    code, out, err = run("import", path, "-o", tmp_path / "plain.npz")
    assert code == 0 and "joint_mask" not in np.load(tmp_path / "plain.npz")
