"""Bad input, measured: every reader's defects through every file command that reads them.

Each case (``cases.py``) writes one bad file beside the good files its command needs and runs
the command in-process (click's CliRunner). It must: exit 1; print exactly one ``error: ...``
line that names the bad file and says what is wrong with it in the user's words (no Python
exception names, no traceback); leave no output or temporary file anywhere; leave every input
byte-identical; run no code from a pickle. A few cases run as real processes, for the exit
status and stderr a shell sees.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import subprocess
import sys
import threading
import time
import warnings
import zipfile
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.npz_archive import read_npz, write_npz
from tests.bad_input import files as F
from tests.bad_input.cases import COMMANDS, MARKER, READER_COMMANDS, Case, cases
from tests.conftest import tree_digest

CASES = cases()
REPO = Path(__file__).resolve().parents[2]

#: words that give away an internal failure rather than a refusal in the user's words
_INTERNAL = re.compile(
    r"Traceback|MDVAE_DEBUG|\b[A-Za-z]*(Error|Exception|Warning)\b|\bFile \"|<[a-z]+ object"
)


@cache
def _good_bytes(kind: str) -> bytes:
    """A good file of ``kind``: what the bad files of its reader are made from."""
    return {
        "npz": F.good_motion,
        "bvh": lambda: F.bvh_text().encode(),
        "asf": lambda: F.asf_text().encode(),
        "amc": lambda: F.amc_text(frames=32).encode(),
        "body-npz": lambda: F.npz_bytes(F.body_members()),
        "body-pkl": F.body_pickle,
    }[kind]()


def _good_name(kind: str) -> str:
    return {"npz": "good.npz", "bvh": "good.bvh", "asf": "good.asf", "amc": "good_01.amc",
            "body-npz": "body.npz", "body-pkl": "body.pkl"}[kind]  # fmt: skip


def _setup(case: Case, folder: Path) -> tuple[Path, dict[str, Path]]:
    """Write the case's bad file and the good files its command needs under ``folder/in``."""
    inputs = folder / "in"
    inputs.mkdir(exist_ok=True)
    bad = inputs / f"bad{case.defect.file_suffix}"
    bad.write_bytes(case.defect.build(folder))
    good = {}
    for kind in case.command.needs:
        good[kind] = inputs / _good_name(kind)
        good[kind].write_bytes(_good_bytes(kind))
    return bad, good


def _listing(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")}


def check_refusal(output: str, bad: Path, expect: str) -> str:
    """The one ``error:`` line of ``output``, checked; other lines may only be notes."""
    lines = [line for line in output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, lines
    others = [line for line in lines if not line.startswith(("error: ", "note: ", "warning: "))]
    assert not others, lines
    line = errors[0]
    assert bad.name in line, line
    assert re.search(expect, line), f"{expect!r} not in {line!r}"
    assert not _INTERNAL.search(output), output
    return line


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_in_one_line(case: Case, tmp_path: Path):
    bad, good = _setup(case, tmp_path)
    before = tree_digest(tmp_path / "in")
    listing = _listing(tmp_path)
    out = tmp_path / "out"
    args = [str(a) for a in case.command.args(bad, good, out)]
    result = CliRunner().invoke(cli, args)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    assert result.exit_code == 1, result.output
    check_refusal(result.output, bad, case.defect.expect)
    assert not (tmp_path / MARKER).exists(), "code from a pickle ran"
    assert not out.exists(), sorted(_listing(out))  # no output, not even an empty folder
    assert _listing(tmp_path) == listing  # no temporary left anywhere
    assert tree_digest(tmp_path / "in") == before  # inputs untouched


def test_the_suite_is_big_enough_and_covers_every_command():
    """At least 150 cases; every command of every reader gets some of its reader's defects."""
    assert len(CASES) >= 150
    ran = {(c.defect.reader, c.command.name) for c in CASES}
    for reader, group in READER_COMMANDS.items():
        for command in COMMANDS[group]:
            assert (reader, command.name) in ran, (reader, command.name)


#: a run of each command group on the good files the bad ones are made from
_GOOD_RUNS = {
    "npz-add-noise": lambda g, o: ["add-noise", g["npz"], "-o", o / "o.npz"],
    "npz-export-mesh": lambda g, o: ["export-mesh", g["npz"], "-o", o / "meshes"],
    "bvh-import": lambda g, o: ["import", g["bvh"], "-o", o / "o.npz"],
    "amc-import": lambda g, o: ["import", g["amc"], "--asf", g["asf"], "-o", o / "o.npz"],
    "body-npz": lambda g, o: [
        "export-bvh",
        g["npz"],
        "--body-model",
        g["body-npz"],
        "-o",
        o / "o.bvh",
    ],  # fmt: skip
    "body-pkl": lambda g, o: [
        "export-bvh",
        g["npz"],
        "--body-model",
        g["body-pkl"],
        "-o",
        o / "o.bvh",
    ],  # fmt: skip
}


@pytest.mark.parametrize("run", list(_GOOD_RUNS))
def test_the_good_files_are_accepted(tmp_path, run):
    """The files the bad ones are made from are read without complaint (so each case fails
    for its own defect)."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    good = {}
    for kind in ("npz", "bvh", "asf", "amc", "body-npz", "body-pkl"):
        good[kind] = inputs / _good_name(kind)
        good[kind].write_bytes(_good_bytes(kind))
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, [str(a) for a in _GOOD_RUNS[run](good, out)])
    assert result.exit_code == 0, result.output
    assert not any(line.startswith("error") for line in result.output.splitlines())
    assert len(list(out.iterdir())) == 1


#: cases run as real processes: the exit status and stderr a shell sees
_PROCESS_CASES = ["npz-huge-shape-add-noise", "npz-pickled-poses-add-noise",
                  "bvh-deep-hierarchy-import"]  # fmt: skip


@pytest.mark.parametrize("case_id", _PROCESS_CASES)
def test_bad_input_in_a_real_process(case_id: str, tmp_path: Path):
    case = next(c for c in CASES if c.id == case_id)
    bad, good = _setup(case, tmp_path)
    before = tree_digest(tmp_path / "in")
    args = [str(a) for a in case.command.args(bad, good, tmp_path / "out")]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    env.pop("MDVAE_DEBUG", None)
    proc = subprocess.run([sys.executable, "-m", "mdvae_cli.cli.main", *args], env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    assert proc.stdout == ""
    check_refusal(proc.stderr, bad, case.defect.expect)
    assert not (tmp_path / MARKER).exists() and not (tmp_path / "out").exists()
    assert tree_digest(tmp_path / "in") == before


def _extras() -> dict[str, np.ndarray]:
    """Extra keys that np.savez could not write (its own parameters) or that are paths."""
    return {
        "file": np.arange(3.0),
        "allow_pickle": np.array([1, 2]),
        "../../escape": np.ones(2),
        "/abs/olute": np.zeros(1),
        "back\\slash": np.array(7),
    }


@pytest.mark.parametrize("command", ["add-noise", "denoise", "sample"])
def test_extra_keys_are_carried_or_renamed_with_a_warning(tmp_path: Path, command: str):
    """``file`` and ``allow_pickle`` (np.savez's parameters) are written back as they are;
    keys that are paths are renamed, one ``warning:`` line each; none is dropped silently
    (``sample`` makes a new motion: it says which per-frame keys it leaves out)."""
    src = tmp_path / "take.npz"
    members = F.motion_members()
    members.update({f"{k}.npy": v for k, v in _extras().items()})
    members["dmpls.npy"] = np.arange(F.FRAMES * 8.0).reshape(F.FRAMES, 8)
    src.write_bytes(F.npz_bytes(members))
    out = tmp_path / "out.npz"
    args = {"add-noise": ["add-noise", src, "-o", out], "denoise": ["denoise", src, "-o", out],
            "sample": ["sample", "--from", src, "--frames", 4, "-o", out]}[command]  # fmt: skip
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 3, result.output
    for old, new in (("../../escape", "escape"), ("/abs/olute", "abs_olute"),
                     ("back\\slash", "back_slash")):  # fmt: skip
        assert any(repr(old) in w and repr(new) in w and "take.npz" in w for w in warnings)
    with zipfile.ZipFile(out) as zf:
        names = zf.namelist()
    assert not any("/" in n or "\\" in n for n in names), names
    written = read_npz(out, out)
    expected = {"file": "file", "allow_pickle": "allow_pickle", "../../escape": "escape",
                "/abs/olute": "abs_olute", "back\\slash": "back_slash"}  # fmt: skip
    for old, new in expected.items():
        np.testing.assert_array_equal(written[new], _extras()[old])
    left_out = "per-frame keys of the start file are not carried into the sample: dmpls"
    assert ("dmpls" in written) == (command != "sample")
    assert (left_out in result.output) == (command == "sample"), result.output


def test_the_npz_writer_takes_any_safe_key_and_refuses_paths():
    buf = io.BytesIO()
    arrays = {"file": np.arange(2), "allow_pickle": np.ones(1), "compress": np.zeros(3)}
    write_npz(buf, arrays)
    buf.seek(0)
    back = read_npz(buf, "memory")
    assert list(back) == list(arrays)
    for key in arrays:
        np.testing.assert_array_equal(back[key], arrays[key])
    for key in ("../x", "/abs", "a\\b", "..", "", "c:d"):
        with pytest.raises(InputError, match="its name is a path"):
            write_npz(io.BytesIO(), {key: np.zeros(1)})


def test_a_failed_write_leaves_no_folder_it_made(tmp_path: Path):
    kept = tmp_path / "kept"
    kept.mkdir()
    target = kept / "new" / "deeper" / "out.npz"

    def fail(tmp: Path) -> None:
        tmp.write_bytes(b"partial")
        raise InputError("refused halfway")

    with pytest.raises(InputError, match="refused halfway"):
        write_atomic(target, fail)
    assert kept.exists() and list(kept.iterdir()) == []


def _wild_motions() -> dict[str, dict[str, np.ndarray]]:
    """Motions that are odd but within every limit: positions jumping 18 km between frames
    with angles of up to 6 rad, and a take whose joints are missing in all but two frames."""
    rng = np.random.default_rng(0)
    wild = F.motion_arrays(T=40, width=66, num_betas=10)
    wild["trans"] = rng.choice([-9e3, 9e3], size=(40, 3))
    wild["poses"] = rng.uniform(-6, 6, (40, 66))
    holes = F.motion_arrays(T=90, width=66, num_betas=10)
    holes["poses"][1:89, 3:] = np.nan
    return {"wild": wild, "holes": holes}


@pytest.mark.parametrize("name", ["wild", "holes"])
def test_odd_motions_within_the_limits_are_denoised_without_python_warnings(tmp_path, name):
    """A gate's exp overflowing, a channel never seen: numbers numpy would warn of, not the
    user's concern; the command says nothing in Python's words."""
    src = tmp_path / f"{name}.npz"
    np.savez(src, **_wild_motions()[name])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = CliRunner().invoke(cli, ["denoise", str(src), "-o", str(tmp_path / "o.npz")])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert result.exit_code == 0, result.output
    assert not _INTERNAL.search(result.output), result.output


@pytest.mark.parametrize("command", ["denoise", "eval"])
def test_a_motion_whose_arrays_add_up_past_the_limit_is_refused_before_reading(
    tmp_path, monkeypatch, command
):
    """Every array under the one-array limit, together over the file's (a 11 MB file of six
    400 MB members of zeros took 2.8 GB): refused before any array is read. The limits are
    made small here: the file holds two extra arrays of 3 kB against 4 kB for the file."""
    from mdvae_cli.formats import npz_io

    members = F.motion_members()
    members.update({f"extra{i}.npy": np.zeros(384) for i in range(2)})
    src = tmp_path / "many.npz"
    src.write_bytes(F.npz_bytes(members, compress=True))
    good = tmp_path / "good.npz"
    good.write_bytes(F.good_motion())
    monkeypatch.setattr(npz_io, "MAX_TOTAL", 4096)
    before = tree_digest(tmp_path)
    args = {"denoise": ["denoise", src, "-o", tmp_path / "out" / "o.npz"],
            "eval": ["eval", "--gt", src, "--pred", good]}[command]  # fmt: skip
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 1, result.output
    check_refusal(result.output, src, r"its arrays add up to [\d.]+ kB unzipped, over the 4\.1 kB")
    assert tree_digest(tmp_path) == before
    monkeypatch.setattr(npz_io, "MAX_TOTAL", 1 << 20)  # the same file under a larger limit
    assert CliRunner().invoke(cli, [str(a) for a in args]).exit_code == 0


@pytest.mark.parametrize("kind", ["body", "checkpoint"])
def test_body_models_and_checkpoints_past_their_limit_are_refused_before_reading(
    tmp_path, monkeypatch, kind
):
    """A body model's or a checkpoint's arrays together past the file's limit (a 3.7 MB body
    model of an 800 MB shapedirs took 1.7 GB): refused before any array is read. The limits
    are made small here (4 kB against the good files' own arrays)."""
    from mdvae_cli.body import formats as body_formats
    from mdvae_cli.model import checkpoint

    (tmp_path / "in").mkdir()
    good = tmp_path / "in" / "good.npz"
    good.write_bytes(F.good_motion())
    bad = tmp_path / "in" / "bad.npz"
    if kind == "body":
        bad.write_bytes(F.npz_bytes(F.body_members()))
        monkeypatch.setattr(body_formats, "MAX_NPZ_BYTES", 4096)
        args = ["export-bvh", good, "--body-model", bad, "-o", tmp_path / "out" / "o.bvh"]
    else:
        bad.write_bytes(F.checkpoint_with(tmp_path, None, None))
        monkeypatch.setattr(checkpoint, "MAX_WEIGHT_BYTES", 4096)
        args = ["denoise", good, "--denoiser", bad, "-o", tmp_path / "out" / "o.npz"]
    before = tree_digest(tmp_path)
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 1, result.output
    check_refusal(
        result.output, bad, r"its arrays add up to [\d.]+ [kM]B unzipped, over the 4\.1 kB"
    )
    assert tree_digest(tmp_path) == before


@pytest.mark.parametrize("chunk", [1, 7, 64, 1 << 22])
def test_bvh_motion_data_read_a_piece_at_a_time_is_the_same(tmp_path, monkeypatch, chunk):
    """The motion data is parsed a piece at a time into one array (a 230 MB take took 2.9 GB
    as a list of words): pieces of any size give the same frames and the same refusals."""
    from mdvae_cli.formats import bvh

    monkeypatch.setattr(bvh, "_CHUNK", chunk)
    path = tmp_path / "take.bvh"
    path.write_text(F.bvh_text(frames=5))
    rows = F.bvh_text(frames=5).split("Frame Time: 0.0333333\n")[1].split()
    expected = np.array(rows, dtype=np.float64).reshape(5, -1)
    np.testing.assert_array_equal(bvh.load_bvh(path, drop_first=False).layout.data, expected)
    for text, words in ((F.bvh_text(frames=5) + "0 0\n", r"not a multiple of the 66 channels"),
                        (F.bvh_text(frames=5) + "x\n", r"non-numeric value"),
                        (F.bvh_text(frames=5).replace("Frames: 5", "Frames: 4"),
                         r"header says 4 frames but the file holds 5")):  # fmt: skip
        path.write_text(text)
        with pytest.raises(InputError, match=words):
            bvh.load_bvh(path)


def _unblock_later(fifo: Path, seconds: float = 5.0) -> None:
    """Open ``fifo`` for writing after ``seconds`` and close it: a reader that waits on it
    gets an empty file, so that a regression fails the test instead of hanging it."""

    def unblock() -> None:
        time.sleep(seconds)
        with contextlib.suppress(OSError):  # nobody reading: nothing to unblock
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))

    threading.Thread(target=unblock, daemon=True).start()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("option", ["asf", "body-model", "checkpoint-json"])
def test_a_fifo_named_by_an_option_is_refused_without_waiting(tmp_path, option):
    """--asf, --body-model and a checkpoint's metadata beside it: a FIFO is said to be one
    (it was "no such skeleton file", "not found", or a wait forever)."""
    (tmp_path / "in").mkdir()
    fifo = tmp_path / "in" / {"asf": "bad.asf", "body-model": "bad.npz",
                              "checkpoint-json": "bad.json"}[option]  # fmt: skip
    os.mkfifo(fifo)
    good = tmp_path / "in" / "good.npz"
    good.write_bytes(F.good_motion())
    amc = tmp_path / "in" / "good_01.amc"
    amc.write_text(F.amc_text(frames=32))
    weights = tmp_path / "in" / "bad.npz"
    if option == "checkpoint-json":
        weights.write_bytes(F.npz_bytes({"w.npy": np.zeros(3)}))
    args = {"asf": ["import", amc, "--asf", fifo, "-o", tmp_path / "out" / "t.npz"],
            "body-model": ["eval", "--gt", good, "--pred", good, "--body-model", fifo],
            "checkpoint-json": ["denoise", good, "--denoiser", weights,
                                "-o", tmp_path / "out" / "c.npz"]}[option]  # fmt: skip
    _unblock_later(fifo)
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 1, result.output
    check_refusal(result.output, fifo, r"is a FIFO \(named pipe\), not a file")
    assert not (tmp_path / "out").exists()


_JOINT_MAPS = {
    "binary": (F.good_motion(), r"not UTF-8 text; a joint map is a JSON file"),
    "deep": (b"[" * 100_000 + b"]" * 100_000, r"nested too deep; a joint map is one flat JSON"),
    "a-list": (b'["LeftUpLeg"]', r'a joint map is a JSON object \{"left_hip": "LeftUpLeg"'),
}


@pytest.mark.parametrize("command", ["import", "denoise"])
@pytest.mark.parametrize("defect", list(_JOINT_MAPS))
def test_a_bad_joint_map_is_refused_in_one_line(tmp_path, command, defect):
    (tmp_path / "in").mkdir()
    take = tmp_path / "in" / "take.bvh"
    take.write_text(F.bvh_text())
    bad = tmp_path / "in" / "map.json"
    bad.write_bytes(_JOINT_MAPS[defect][0])
    before = tree_digest(tmp_path / "in")
    args = [command, take, "--joint-map", bad, "-o", tmp_path / "out" / "t.npz"]
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 1, result.output
    check_refusal(result.output, bad, _JOINT_MAPS[defect][1])
    assert not (tmp_path / "out").exists() and tree_digest(tmp_path / "in") == before
