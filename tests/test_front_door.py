"""The README's promise, command by command: every file command takes a folder and answers
``--json``; files are read and written through one front door (``formats.registry``); refusals
are one line in the user's words (issue 33)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from mdvae_cli.cli.eval_cmd import results_table
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats import registry
from mdvae_cli.formats.registry import ReadOptions, read, write
from mdvae_cli.metrics import EvalResult
from tests.bad_input import files as F
from tests.conftest import one_error_line as one_error
from tests.conftest import run_cli as run
from tests.conftest import tree_digest


@pytest.fixture
def takes(make_motion_file, tmp_path) -> Path:
    """A folder of two small motions, one a level down."""
    make_motion_file("takes/a.npz", T=40, seed=1)
    make_motion_file("takes/sub/b.npz", T=36, seed=2)
    return tmp_path / "takes"


# --- every command: a folder in, --json out -------------------------------------------------


FOLDER_COMMANDS = {
    "add-noise": lambda d, o: ["add-noise", d, "-o", o / "noisy", "--sigma", 0.1],
    "export-bvh": lambda d, o: ["export-bvh", d, "-o", o / "bvh"],
    "export-mesh": lambda d, o: ["export-mesh", d, "-o", o / "meshes", "--every", 20],
    "view": lambda d, o: ["view", d, "-o", o / "page.html", "--no-mesh"],
    "plot": lambda d, o: ["plot", d, "-o", o / "figure.svg", "--frames", 2],
    "eval": lambda d, o: ["eval", "--gt", d, "--pred", d],
}


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_every_file_command_takes_a_folder_and_answers_json(takes, tmp_path, command):
    out = tmp_path / "out"
    code, stdout, err = run(*FOLDER_COMMANDS[command](takes, out), "--json")
    assert code == 0, err
    data = json.loads(stdout)  # one JSON document on stdout, nothing else there
    if "files" in data:  # the per-file commands
        assert len(data["files"]) == 2 and all(f["ok"] for f in data["files"])
    else:  # view and plot: one output made of every file
        assert data["failed"] == 0 and len(data["motions"]) == 2
        assert Path(data["output"]).is_file()


#: the file commands run on a folder by the tests below rather than the loop above
FOLDER_TESTED_APART = {"denoise", "import"}


def test_every_command_has_json_and_every_file_command_is_run_on_a_folder():
    for name, command in cli.commands.items():
        assert "as_json" in {p.name for p in command.params}, name
    takes_inputs = {
        name for name, c in cli.commands.items() if "inputs" in {p.name for p in c.params}
    }
    assert takes_inputs - {"eval"} <= set(FOLDER_COMMANDS) | FOLDER_TESTED_APART
    assert "eval" in FOLDER_COMMANDS  # --gt and --pred folders


def test_import_takes_a_folder_of_takes_and_answers_json(tmp_path):
    for name in ("a.bvh", "sub/b.bvh"):
        (tmp_path / "mocap" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "mocap" / name).write_text(F.bvh_text(frames=30))
    code, stdout, err = run("import", tmp_path / "mocap", "-o", tmp_path / "out", "--json")
    assert code == 0, err
    data = json.loads(stdout)
    assert [f["ok"] for f in data["files"]] == [True, True]


def test_denoise_and_sample_answer_json(takes, tmp_path):
    code, stdout, err = run("denoise", takes, "-o", tmp_path / "clean", "--json", "--feet", "off")
    assert code == 0, err
    data = json.loads(stdout)
    assert data["succeeded"] == 2 and data["mode"] == "regression+offset"
    code, stdout, err = run("sample", "--from", takes / "a.npz", "--frames", 10,
                            "-o", tmp_path / "s.npz", "--json")  # fmt: skip
    assert code == 0, err
    assert json.loads(stdout)["frames"] == 10


def test_add_noise_prints_a_summary_line(takes, tmp_path):
    code, out, err = run("add-noise", takes, "-o", tmp_path / "noisy")
    assert code == 0 and out == ""
    assert "wrote 2 noisy file(s), 76 frames" in err


def test_a_failed_file_lists_no_output(takes, tmp_path):
    (takes / "bad.npz").write_bytes(b"not a zip")
    code, stdout, _ = run("add-noise", takes, "-o", tmp_path / "noisy", "--json")
    assert code == 1
    rows = {f["file"]: f for f in json.loads(stdout)["files"]}
    assert rows["bad.npz"]["ok"] is False and rows["bad.npz"]["output"] is None
    assert rows["a.npz"]["output"] is not None and not (tmp_path / "noisy" / "bad.npz").exists()


def test_view_of_a_mixed_folder_shows_the_good_files_and_names_the_bad(takes, tmp_path):
    (takes / "bad.npz").write_bytes(b"")
    code, stdout, err = run("view", takes, "-o", tmp_path / "p.html", "--no-mesh", "--json")
    assert code == 1 and "bad.npz: empty file" in err
    data = json.loads(stdout)
    assert len(data["motions"]) == 2 and data["failed"] == 1
    assert (tmp_path / "p.html").is_file()


# --- one reader for every format --------------------------------------------------------------


@pytest.fixture
def wham(tmp_path) -> Path:
    path = tmp_path / "wham_output.pkl"
    path.write_bytes(F.wham_bytes(frames=40))
    return path


def test_export_bvh_and_eval_read_what_denoise_reads(wham, tmp_path):
    code, _, err = run("export-bvh", wham, "-o", tmp_path / "w.bvh")
    assert code == 0, err
    bvh = tmp_path / "w.bvh"
    assert bvh.read_text().startswith("HIERARCHY")
    code, stdout, err = run("eval", "--gt", wham, "--pred", wham, "--json")
    assert code == 0, err
    result = json.loads(stdout)["files"][0]["result"]
    assert result["mpjpe_cm"] == pytest.approx(0, abs=1e-6)
    assert result["mpjpe_root_cm"] == pytest.approx(0, abs=1e-6)
    # a BVH as ground truth: read (retargeted) like any other file, not "convert it first"
    code, stdout, err = run("eval", "--gt", bvh, "--pred", bvh, "--json")
    assert code == 0, err


def test_wrong_output_forms_are_named_in_the_users_words(wham, tmp_path):
    line = one_error(*run("denoise", wham, "-o", tmp_path / "x.bvh"))
    assert "wham_output.pkl: a .pkl file, not a BVH take: write it as .pkl or .npz" in line
    assert "is an .npz file" not in line
    line = one_error(*run("add-noise", wham, "-o", tmp_path / "clean.fbx"))
    assert "cannot write" in line and "does not write FBX; write .npz or .bvh" in line
    assert not (tmp_path / "clean.fbx").exists()  # not silently a folder


def test_unsupported_inputs_say_what_to_do(tmp_path):
    (tmp_path / "take.fbx").write_bytes(b"")
    line = one_error(*run("denoise", tmp_path / "take.fbx", "-o", tmp_path / "c.npz"))
    assert "take.fbx: FBX is not supported: export the take as BVH" in line
    assert "StopIteration" not in line
    (tmp_path / "m.c3d").write_bytes(b"\x02\x50")
    with pytest.raises(InputError, match="C3D marker files are not supported"):
        read(tmp_path / "m.c3d")


def test_write_refuses_a_motion_no_reader_would_take(make_motion_file, tmp_path):
    motion = read(make_motion_file("m.npz", T=10)).single()
    motion.pose_body[3, 0] = 1e30
    with pytest.raises(InputError, match="a body-joint rotation holds an angle of 1e\\+30 rad"):
        write(motion, tmp_path / "out.npz")
    assert not (tmp_path / "out.npz").exists()
    with pytest.raises(InputError, match="AMC is written only for an AMC take"):
        write(read(make_motion_file("n.npz", T=10)), tmp_path / "out.amc")


def test_a_bvh_with_a_byte_order_mark_is_read(tmp_path):
    plain, bom = tmp_path / "plain.bvh", tmp_path / "bom.bvh"
    plain.write_text(F.bvh_text(frames=30))
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read(plain).single(), read(bom).single()
    np.testing.assert_array_equal(a.pose_body, b.pose_body)


def test_import_takes_a_joint_map(tmp_path):
    take = tmp_path / "take.bvh"
    take.write_text(F.bvh_text(frames=30))
    good, deep = tmp_path / "map.json", tmp_path / "deep.json"
    good.write_text(json.dumps({}))
    code, _, err = run("import", take, "-o", tmp_path / "t.npz", "--joint-map", good)
    assert code == 0, err
    deep.write_text("[" * 100_000 + "]" * 100_000)
    line = one_error(*run("import", take, "-o", tmp_path / "u.npz", "--joint-map", deep))
    assert "deep.json: nested too deep" in line and "RecursionError" not in line


# --- inputs that are not files, and the same file twice ----------------------------------------


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("command", ["eval", "denoise", "add-noise", "view"])
def test_a_fifo_is_refused_without_waiting(tmp_path, make_motion_file, command):
    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    good = make_motion_file("g.npz", T=10)
    args = {
        "eval": ["eval", "--gt", fifo, "--pred", good],
        "denoise": ["denoise", fifo, "-o", tmp_path / "c.npz"],
        "add-noise": ["add-noise", fifo, "-o", tmp_path / "n.npz"],
        "view": ["view", fifo, "-o", tmp_path / "p.html"],
    }[command]
    line = one_error(*run(*args))
    assert "pipe.npz is a FIFO (named pipe), not a file" in line
    assert "must be a folder" not in line


def test_a_device_is_refused_for_what_it_is(tmp_path):
    line = one_error(*run("add-noise", "/dev/zero", "-o", tmp_path / "n.npz"))
    assert "/dev/zero is a device or socket, not a file" in line


def test_the_same_file_named_twice_is_one_input(make_motion_file, tmp_path):
    src = make_motion_file("a.npz", T=10)
    code, _, err = run("add-noise", src, src, "-o", tmp_path / "n.npz")
    assert code == 0, err
    assert (tmp_path / "n.npz").is_file()


# --- option values, Ctrl-C, eval's table -------------------------------------------------------


def test_a_bad_option_value_is_one_line_and_exit_1(make_motion_file, tmp_path):
    src = make_motion_file("a.npz", T=10)
    line = one_error(*run("add-noise", src, "-o", tmp_path / "n.npz", "--sigma", "-1"))
    assert "Invalid value for '--sigma': -1 is not >= 0 (see " in line and "add-noise -h)" in line
    line = one_error(*run("eval", "--gt", src))
    assert "Missing option '--pred'" in line


def test_ctrl_c_during_export_mesh_leaves_nothing_behind(make_motion_file, tmp_path, monkeypatch):
    import trimesh

    src = make_motion_file("a.npz", T=30)
    real, calls = trimesh.Trimesh.export, []

    def export(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 7:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(trimesh.Trimesh, "export", export)
    before = tree_digest(tmp_path)
    code, _, err = run("export-mesh", src, "-o", tmp_path / "deep" / "meshes")
    assert code == 130 and "interrupted" in err
    assert tree_digest(tmp_path) == before and not (tmp_path / "deep").exists()


def _result(seed: int) -> EvalResult:
    rng = np.random.default_rng(seed)
    names = ("v2v_cm", "v2v_abs_cm", "mpjpe_cm", "mpjpe_root_cm", "accel_gt", "accel_pred",
             "accel_error", "foot_skate_gt", "foot_skate_pred", "foot_slide_gt",
             "foot_slide_pred", "penetration_gt", "penetration_pred", "float_gt",
             "float_pred")  # fmt: skip
    values = {n: float(x) for n, x in zip(names, rng.uniform(0.5, 99, len(names)), strict=True)}
    return EvalResult(num_frames=40, fps=30.0, **values)


@pytest.mark.parametrize("width", [80, 100, 200])
def test_eval_table_fits_the_console(width):
    rows = [(f"clip_{i:02d}_with_a_long_name.npz", _result(i)) for i in range(3)]
    console = Console(width=width, record=True, file=open(os.devnull, "w"))  # noqa: SIM115
    for table in results_table(rows, _result(9), width):
        console.print(table)
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= width
    assert "MPJPE root" in text and "MPJPE world" in text and "…" not in text


# --- limits that hold while reading -----------------------------------------------------------


def test_limits_hold_while_unzipping(tmp_path, make_motion_file, monkeypatch):
    from mdvae_cli.formats import npz_io, source

    src = make_motion_file("a.npz", T=20)
    monkeypatch.setattr(npz_io, "MAX_MEMBER", 100)
    with pytest.raises(InputError, match=r"'poses' is .* over the 100 bytes one array"):
        read(src)
    take = tmp_path / "blank.bvh.gz"
    take.write_bytes(F.gz(F.bvh_text(frames=8) + "\n" * 5000))
    monkeypatch.setattr(source, "MAX_TEXT", 4000)
    with pytest.raises(InputError, match="over 0 MiB of text"):
        read(take)


def test_the_registry_knows_every_suffix_it_reads():
    assert set(registry.READ_SUFFIXES) >= {".npz", ".bvh", ".amc", ".pkl", ".pt", ".npy"}
    assert not set(registry.READ_SUFFIXES) & set(registry.UNSUPPORTED)
    assert ReadOptions().format is None


def test_a_file_name_too_long_is_said_in_words(make_motion_file, tmp_path):
    long = tmp_path / ("a" * 300 + ".npz")
    line = one_error(*run("add-noise", long, "-o", tmp_path / "n.npz"))
    assert line.endswith(".npz: File name too long") and "Errno" not in line
    src = make_motion_file("m.npz", T=10)
    line = one_error(*run("add-noise", src, "-o", long))
    assert "File name too long" in line and "OSError" not in line


def test_a_broken_skeleton_is_blamed_not_the_take(tmp_path):
    (tmp_path / "s.asf").write_text("garbage\n")
    take = tmp_path / "s_01.amc"
    take.write_text(F.amc_text(frames=32))
    line = one_error(*run("import", take, "-o", tmp_path / "o.npz"))
    assert line.startswith(f"error: {tmp_path / 's.asf'}: not an ASF skeleton")
    assert line.endswith(f"(reading {take})")
