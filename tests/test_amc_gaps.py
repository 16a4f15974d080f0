"""Frame numbers in AMC takes: missing numbers are holes at their times, filled by ``denoise``
(``--fill off``: the frames the file came with alone); numbers out of order are sorted, a number
listed twice is refused in one line (``formats.amc_frames``)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.amc_write import amc_text
from mdvae_cli.formats.asfamc import load_amc
from tests.test_amc_out import amc_file, asf_text, motion_values

T = 120
GAP = range(40, 50)  # rows of the take left out: frame numbers 41-50
FRAME_LINES = 30  # a generated frame: its number, the root and 28 bones with dofs


def frames_of(text: str) -> tuple[str, list[str]]:
    """An AMC text as (header, each frame's block: its number line and bone lines)."""
    head, *frames = re.split(r"\n(?=\d+\n)", text.rstrip("\n"))
    return head, frames


def joined(head: str, frames: list[str]) -> str:
    return "\n".join([head, *frames]) + "\n"


def numbers(path: Path) -> list[str]:
    """The frame numbers of an AMC file, in file order."""
    return [ln.strip() for ln in path.read_text().splitlines() if re.fullmatch(r"\d+", ln.strip())]


def run(*args) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    """A generated take (``full_01.amc``), the same without frames 41-50 (``gap_01.amc``), and
    ``denoise`` of both ({"full", "on", "off"}: the output's path and ``--json`` result)."""
    folder = tmp_path_factory.mktemp("gaps")
    (folder / "gen.asf").write_text(asf_text())
    values = motion_values(T)
    head, frames = frames_of(amc_file(values))
    (folder / "full_01.amc").write_text(joined(head, frames))
    (folder / "gap_01.amc").write_text(joined(head, [f for i, f in enumerate(frames)
                                                     if i not in GAP]))  # fmt: skip
    runs = {}
    for name, take, extra in (("full", "full_01", ()), ("on", "gap_01", ()),
                              ("off", "gap_01", ("--fill", "off"))):  # fmt: skip
        out = folder / f"{name}.amc"
        code, text, err = run("denoise", folder / f"{take}.amc", "-o", out, "--json", *extra)
        assert code == 0, err
        runs[name] = (out, json.loads(text)["files"][0]["result"])
    return folder, values, runs


def test_missing_numbers_read_as_holes_at_their_times(takes):
    folder, values, _ = takes
    src = load_amc(folder / "gap_01.amc", folder / "gen.asf")
    layout = src.layout
    assert src.num_frames == T and layout.frames == [str(n) for n in range(1, T + 1)]
    assert np.flatnonzero(layout.gaps()).tolist() == list(GAP)
    assert src.info["frames_in_file"] == T - len(GAP) and src.info["missing_frames"] == len(GAP)
    assert any("frame numbers 41-50 missing (10 frame(s) in 1 gap(s))" in n for n in src.notes)
    keep = np.ones(T, bool)
    keep[list(GAP)] = False
    full = load_amc(folder / "full_01.amc", folder / "gen.asf")
    np.testing.assert_allclose(src.rotations[keep], full.rotations[keep], atol=1e-12)
    np.testing.assert_allclose(src.root_positions[keep], full.root_positions[keep], atol=1e-12)
    # with its gaps left out, the layout writes the file back byte for byte
    text = (folder / "gap_01.amc").read_text()
    assert amc_text(layout, layout.values, gaps=False) == text


def test_denoise_fills_the_gap_between_its_neighbours(takes):
    folder, values, runs = takes
    out, result = runs["on"]
    assert result["filled_frames"] == len(GAP) and result["frames"] == T
    assert numbers(out) == [str(n) for n in range(1, T + 1)]
    filled = load_amc(out, folder / "gen.asf").layout.values
    tol = 0.5  # degrees (root translation: file units, 1/80 inch)
    for bone, v in filled.items():
        g = v[GAP.start : GAP.stop]
        beside = np.concatenate([v[GAP.start - 5 : GAP.start], v[GAP.stop : GAP.stop + 5]])
        assert np.all(g >= beside.min(axis=0) - tol) and np.all(g <= beside.max(axis=0) + tol), bone
        np.testing.assert_allclose(g, values[bone][GAP.start : GAP.stop], atol=tol, err_msg=bone)


def test_observed_frames_come_back_as_a_whole_take_gives_them(takes):
    folder, _, runs = takes
    gap = load_amc(runs["on"][0], folder / "gen.asf").layout.values
    whole = load_amc(runs["full"][0], folder / "gen.asf").layout.values
    keep = np.ones(T, bool)
    keep[list(GAP)] = False
    for bone in whole:
        np.testing.assert_allclose(gap[bone][keep], whole[bone][keep], atol=0.01, err_msg=bone)


def test_fill_off_writes_the_frames_it_came_with(takes):
    folder, _, runs = takes
    out, result = runs["off"]
    assert result["filled_frames"] == 0 and result["unfilled_frames"] == len(GAP)
    assert numbers(out) == numbers(folder / "gap_01.amc")
    head_in, frames_in = frames_of((folder / "gap_01.amc").read_text())
    head_out, frames_out = frames_of(out.read_text())
    assert head_out == head_in
    bones = [[ln.split()[0] for ln in f.splitlines()[1:]] for f in frames_in]
    assert [[ln.split()[0] for ln in f.splitlines()[1:]] for f in frames_out] == bones
    # the frames it has: as the filled output has them
    on = load_amc(runs["on"][0], folder / "gen.asf").layout.values
    off = load_amc(out, folder / "gen.asf").layout.values
    keep = np.ones(T, bool)
    keep[list(GAP)] = False
    for bone in on:
        np.testing.assert_allclose(off[bone][keep], on[bone][keep], atol=0.2, err_msg=bone)


def test_frames_out_of_order_are_sorted_with_a_note(tmp_path):
    (tmp_path / "gen.asf").write_text(asf_text())
    head, frames = frames_of(amc_file(motion_values(60)))
    (tmp_path / "in_01.amc").write_text(joined(head, frames))
    shuffled = frames[:20] + [frames[21], frames[20]] + frames[22:50] + frames[51:] + [frames[50]]
    (tmp_path / "mixed_01.amc").write_text(joined(head, shuffled))
    src = load_amc(tmp_path / "mixed_01.amc", tmp_path / "gen.asf")
    ref = load_amc(tmp_path / "in_01.amc", tmp_path / "gen.asf")
    np.testing.assert_array_equal(src.rotations, ref.rotations)
    assert src.layout.frames == ref.layout.frames and not src.layout.gaps().any()
    line = 3 + 21 * FRAME_LINES + 1  # the header's 3 lines, 21 frames, frame 22's number line
    assert f"frame numbers out of order (line {line}: 21 after 22)" in src.notes[-1]
    code, _, err = run("denoise", tmp_path / "mixed_01.amc", "-o", tmp_path / "out.amc")
    assert code == 0 and "frames are taken in the order of their numbers" in err
    assert numbers(tmp_path / "out.amc") == [str(n) for n in range(1, 61)]


def test_a_number_listed_twice_is_one_line(tmp_path):
    (tmp_path / "gen.asf").write_text(asf_text())
    head, frames = frames_of(amc_file(motion_values(30)))
    frames[11] = "11" + frames[11][2:]  # frame 12 numbered 11 again
    (tmp_path / "dup_01.amc").write_text(joined(head, frames))
    code, _, err = run("denoise", tmp_path / "dup_01.amc", "-o", tmp_path / "out.amc")
    assert code != 0 and not (tmp_path / "out.amc").exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    first, second = 3 + 10 * FRAME_LINES + 1, 3 + 11 * FRAME_LINES + 1
    assert f"frame number 11 is listed twice (line {first} and line {second})" in lines[0]


def test_numbering_kept_and_far_numbers_refused(tmp_path):
    (tmp_path / "gen.asf").write_text(asf_text())
    head, frames = frames_of(amc_file(motion_values(40), first=101))
    (tmp_path / "late_01.amc").write_text(joined(head, frames[:15] + frames[18:]))
    src = load_amc(tmp_path / "late_01.amc", tmp_path / "gen.asf")
    assert src.layout.frames == [str(n) for n in range(101, 141)]
    assert np.flatnonzero(src.layout.gaps()).tolist() == [15, 16, 17]
    assert "frame numbers 116-118 missing" in src.notes[-1]
    far = frames[:-1] + ["9000000" + frames[-1][3:]]
    (tmp_path / "far_01.amc").write_text(joined(head, far))
    with pytest.raises(InputError, match=r"frame numbers 101\.\.9000000 for 40 frames"):
        load_amc(tmp_path / "far_01.amc", tmp_path / "gen.asf")


def test_add_noise_keeps_the_holes(takes, tmp_path):
    folder, _, _ = takes
    code, _, err = run("add-noise", folder / "gap_01.amc", "-o", tmp_path / "noisy.amc",
                       "--seed", 1, "--sigma", 0.05)  # fmt: skip
    assert code == 0, err
    assert numbers(tmp_path / "noisy.amc") == numbers(folder / "gap_01.amc")
    code, _, err = run("add-noise", folder / "gap_01.amc", "-o", tmp_path / "noisy.npz",
                       "--seed", 1, "--sigma", 0.05)  # fmt: skip
    assert code == 0, err
    poses = np.load(tmp_path / "noisy.npz")["poses"]
    assert poses.shape[0] == T
    assert np.flatnonzero(np.isnan(poses).any(axis=1)).tolist() == list(GAP)


def test_drop_frames_on_an_amc_take_leaves_their_numbers_out_and_denoise_fills_them(takes):
    """``add-noise --drop-frames`` on an AMC take: the dropped frames' numbers left out (the
    holes the reader reads), the rows the .npz output holds as NaN; the other frames byte for
    byte as they came (--sigma 0). ``denoise`` fills them back, ``eval`` scores every frame."""
    folder, values, runs = takes
    src = folder / "full_01.amc"
    code, out, err = run("add-noise", src, "-o", folder / "drop.amc", "--sigma", 0,
                         "--drop-frames", "10x2", "--seed", 4, "--json")  # fmt: skip
    assert code == 0, err
    assert json.loads(out)["files"][0]["result"]["dropped_frames"] == 20
    code, _, err = run("add-noise", src, "-o", folder / "drop.npz", "--sigma", 0,
                       "--drop-frames", "10x2", "--seed", 4)  # fmt: skip
    assert code == 0, err
    gone = np.flatnonzero(np.isnan(np.load(folder / "drop.npz")["poses"]).all(axis=1))
    assert len(gone) == 20
    kept = [str(n) for n in range(1, T + 1) if n - 1 not in gone]
    assert numbers(folder / "drop.amc") == kept
    head, frames = frames_of(src.read_text())
    assert frames_of((folder / "drop.amc").read_text()) == (
        head,
        [f for i, f in enumerate(frames) if i not in gone],
    )

    code, out, err = run("denoise", folder / "drop.amc", "-o", folder / "drop_filled.amc",
                         "--json")  # fmt: skip
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert result["filled_frames"] == 20 and result["unfilled_frames"] == 0
    assert numbers(folder / "drop_filled.amc") == [str(n) for n in range(1, T + 1)]
    filled = load_amc(folder / "drop_filled.amc", folder / "gen.asf").layout.values
    whole = load_amc(runs["full"][0], folder / "gen.asf").layout.values
    keep = np.ones(T, bool)
    keep[gone] = False
    for bone, v in filled.items():  # degrees; root translation in file units (1/80 inch)
        np.testing.assert_allclose(v[gone], values[bone][gone], atol=0.5, err_msg=bone)
        np.testing.assert_allclose(v[keep], whole[bone][keep], atol=0.05, err_msg=bone)
    code, out, err = run("eval", "--gt", src, "--pred", folder / "drop_filled.amc", "--json")
    assert code == 0, err
    score = json.loads(out)["files"][0]["result"]
    assert score["num_frames"] == T and score["unscored_frames"] == 0
    assert score["mpjpe_cm"] < 1.0


def test_drop_frames_on_an_amc_take_with_its_own_gap_and_what_amc_cannot_hold(takes, tmp_path):
    """The take's own gap (41-50) stays left out beside the dropped frames; a limb missing
    (--drop-joints) is no frame an AMC can leave out: refused in one line for an .amc output."""
    folder, _, _ = takes
    code, _, err = run("add-noise", folder / "gap_01.amc", "-o", tmp_path / "both.amc",
                       "--sigma", 0.05, "--drop-frames", "8", "--seed", 2)  # fmt: skip
    assert code == 0, err
    got = [int(n) for n in numbers(tmp_path / "both.amc")]
    missing = sorted(set(range(1, T + 1)) - set(got))
    assert len(missing) == 18 and set(range(41, 51)) <= set(missing)
    code, out, err = run("add-noise", folder / "full_01.amc", "-o", tmp_path / "limb.amc",
                         "--drop-joints", "10")  # fmt: skip
    assert code == 1 and "Traceback" not in err and not (tmp_path / "limb.amc").exists()
    assert "AMC holds frames missing whole: --drop-frames alone" in err
    # numbered every 2nd frame (one frame in 2 of a capture): a number left out is no hole
    head, frames = frames_of(amc_file(motion_values(40)))
    odd = [str(2 * i + 1) + f[len(str(i + 1)) :] for i, f in enumerate(frames)]
    (folder / "odd_01.amc").write_text(joined(head, odd))
    code, out, err = run("add-noise", folder / "odd_01.amc", "-o", tmp_path / "odd.amc",
                         "--drop-frames", "5")  # fmt: skip
    assert code == 1 and not (tmp_path / "odd.amc").exists()
    assert "frame numbers step by more than 1" in err and "Traceback" not in err
