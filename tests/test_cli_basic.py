"""End-to-end CLI runs on small generated files: add-noise, eval, export-mesh, bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.formats.npz_io import load_motion
from tests.conftest import run_cli as run


@pytest.fixture
def small_default_body(monkeypatch, tiny_body):
    """Make the commands' default body the tiny test body (input-handling tests, not the body)."""
    from mdvae_cli.cli import eval_cmd, export_mesh

    for module in (eval_cmd, export_mesh):
        real = module.load_body_model
        monkeypatch.setattr(
            module,
            "load_body_model",
            lambda path, real=real: tiny_body if path is None else real(path),
        )


def assert_one_error_line(code: int, out: str, err: str) -> str:
    assert code != 0
    assert "Traceback" not in out + err
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: ")
    return lines[0]


def test_help_lists_subcommands():
    code, out, _ = run("--help")
    assert code == 0
    for name in ("add-noise", "eval", "export-mesh"):
        assert name in out


def test_loading_the_cli_and_adding_noise_do_not_import_torch(make_motion_file, tmp_path):
    """`mdvae --help` and `mdvae add-noise` (numpy only) must not pay torch's import (seconds
    on a small machine, per call of a shell loop); the commands that need it load it."""
    import subprocess
    import sys

    src, dst = str(make_motion_file("in.npz")), str(tmp_path / "o.npz")
    code = (
        "import sys\n"
        "from mdvae_cli.cli.main import cli\n"
        f"try:\n    cli(['add-noise', '--sigma', '0.1', {src!r}, '-o', {dst!r}])\n"
        "except SystemExit as e:\n    assert e.code in (0, None), e.code\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"
    assert (tmp_path / "o.npz").exists()


def test_cli_mesh_format_choices_are_the_exporters():
    """The CLI spells the mesh formats out (importing the exporter would load torch)."""
    from mdvae_cli.cli.denoise import denoise as denoise_command
    from mdvae_cli.cli.export_mesh import export_mesh
    from mdvae_cli.export import MESH_FORMATS

    for command, name in ((export_mesh, "fmt"), (denoise_command, "mesh_format")):
        (param,) = [p for p in command.params if p.name == name]
        assert set(param.type.choices) == set(MESH_FORMATS)


@pytest.mark.parametrize("name", ["add-noise", "eval", "export-mesh"])
def test_subcommand_help(name):
    code, out, _ = run(name, "--help")
    assert code == 0 and "Usage: " in out


# --- add-noise + eval --------------------------------------------------------------------------


def test_add_noise_then_eval_json(make_motion_file, tmp_path, hash_tree):
    clean = make_motion_file("clean.npz", T=12, fps=30.0)
    before = hash_tree(tmp_path)
    noisy = tmp_path / "noisy.npz"
    code, out, err = run("add-noise", clean, "-o", noisy, "--sigma", 0.15, "--seed", 3)
    assert code == 0, err
    assert out == ""
    assert hash_tree(tmp_path) == {**before, "noisy.npz": hash_tree(tmp_path)["noisy.npz"]}

    a, b = load_motion(clean), load_motion(noisy)
    assert np.array_equal(a.root_orient, b.root_orient) and np.array_equal(a.trans, b.trans)
    assert np.array_equal(a.pose_extra, b.pose_extra)
    assert 0.05 < (b.pose_body - a.pose_body).std() < 0.3

    code, out, err = run("eval", "--gt", clean, "--pred", noisy, "--json")
    assert code == 0, err
    data = json.loads(out)  # stdout holds exactly one JSON document
    assert set(data) == {"files", "mean", "failed", "unpaired_predictions", "units", "body_model"}
    assert data["failed"] == 0
    (row,) = data["files"]
    assert set(row) == {"file", "gt", "pred", "ok", "error", "result"}  # metrics said once
    assert row["ok"] is True and row["error"] is None and row["file"] == "clean.npz"
    metrics = row["result"]
    keys = {"num_frames", "fps", "v2v_cm", "v2v_abs_cm", "mpjpe_cm", "mpjpe_root_cm",
            "accel_gt", "accel_pred",
            "accel_error", "foot_skate_gt", "foot_skate_pred", "foot_slide_gt", "foot_slide_pred",
            "penetration_gt", "penetration_pred", "float_gt", "float_pred", "floor_m",
            "contact_pairs", "contact_frames", "unscored_frames", "accel_count"}  # fmt: skip
    assert set(metrics) == keys and set(data["mean"]) == keys
    for name in ("foot_skate", "foot_slide", "penetration", "float"):
        assert data["units"][f"{name}_gt"] == data["units"][f"{name}_pred"]
    assert metrics["num_frames"] == 12 and metrics["fps"] == 30.0
    assert metrics["v2v_cm"] > 0.5 and metrics["mpjpe_cm"] > 0.5
    # noise on the body joints only: the pelvis stays, so both MPJPEs agree
    assert metrics["mpjpe_root_cm"] == pytest.approx(metrics["mpjpe_cm"])
    assert metrics["accel_pred"] > metrics["accel_gt"] > 0
    assert metrics["accel_error"] > 0
    assert data["units"]["v2v_cm"] == "cm" and data["units"]["accel_error"] == "m/s^2"

    code, out, err = run("eval", "--gt", clean, "--pred", clean, "--json")
    same = json.loads(out)["files"][0]["result"]
    assert same["v2v_cm"] == pytest.approx(0, abs=1e-9)
    assert same["mpjpe_cm"] == pytest.approx(0, abs=1e-9)
    assert same["accel_error"] == pytest.approx(0, abs=1e-9)


def test_eval_table_on_folders(make_motion_file, tmp_path):
    for rel in ("a/one.npz", "b/two.npz"):
        make_motion_file(Path("gt") / rel, T=6)
    code, _, err = run("add-noise", tmp_path / "gt", "-o", tmp_path / "pred", "--sigma", 0.1)
    assert code == 0, err
    written = sorted(
        p.relative_to(tmp_path / "pred").as_posix() for p in (tmp_path / "pred").rglob("*")
    )
    assert written == ["a", "a/one.npz", "b", "b/two.npz"]
    code, out, err = run("eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred")
    assert code == 0, err
    assert out == ""  # the table is human output, on stderr
    assert "a/one.npz" in err and "b/two.npz" in err and "mean" in err

    code, out, _ = run("eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred", "--json")
    data = json.loads(out)
    rows = [f["result"] for f in data["files"]]
    assert data["mean"]["num_frames"] == 12
    assert data["mean"]["v2v_cm"] == pytest.approx(np.mean([r["v2v_cm"] for r in rows]))


def test_eval_missing_prediction_fails_that_file_only(
    small_default_body, make_motion_file, tmp_path
):
    make_motion_file("gt/x.npz", T=5)
    make_motion_file("gt/y.npz", T=5)
    make_motion_file("pred/x.npz", T=5)
    code, out, err = run("eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred", "--json")
    assert code == 1
    data = json.loads(out)
    assert data["failed"] == 1 and [f["ok"] for f in data["files"]] == [True, False]
    assert "no prediction" in data["files"][1]["error"]
    assert "error: " in err


@pytest.mark.parametrize(
    "pred_kwargs, message",
    [
        ({"fps": 60.0}, "durations differ: ground truth 0.20 s, prediction 0.10 s (at 30 fps)"),
        ({"T": 7}, "lengths differ"),
    ],  # fmt: skip
)
def test_eval_mismatch_is_one_error(small_default_body, make_motion_file, pred_kwargs, message):
    gt = make_motion_file("gt.npz", T=6, fps=30.0)
    pred = make_motion_file("pred.npz", **{"T": 6, "fps": 30.0, **pred_kwargs})
    line = assert_one_error_line(*run("eval", "--gt", gt, "--pred", pred))
    assert message in line


def test_eval_file_against_folder_is_refused(small_default_body, make_motion_file, tmp_path):
    gt = make_motion_file("gt.npz", T=4)
    make_motion_file("preds/gt.npz", T=4)
    assert_one_error_line(*run("eval", "--gt", gt, "--pred", tmp_path / "preds"))


# --- add-noise details -------------------------------------------------------------------------


def test_add_noise_is_deterministic_per_seed_and_path(make_motion_file, tmp_path):
    src = make_motion_file("in/clip.npz", T=8)
    make_motion_file("in/sub/clip.npz", T=8)  # same content, other relative path

    def noisy(out, seed, *extra):
        code, _, err = run("add-noise", tmp_path / "in", "-o", out, "--seed", seed, *extra)
        assert code == 0, err
        return load_motion(out / "clip.npz"), load_motion(out / "sub" / "clip.npz")

    a1, b1 = noisy(tmp_path / "o1", 5)
    a2, _ = noisy(tmp_path / "o2", 5)
    a3, _ = noisy(tmp_path / "o3", 6)
    assert np.array_equal(a1.pose_body, a2.pose_body)
    assert not np.allclose(a1.pose_body, a3.pose_body)
    assert not np.allclose(a1.pose_body, b1.pose_body)
    assert load_motion(src).joint_mask is None


def test_add_noise_options_reach_the_file(make_motion_file, tmp_path):
    src = make_motion_file("c.npz", T=50)
    out = tmp_path / "n.npz"
    code, _, err = run("add-noise", src, "-o", out, "--sigma", 0, "--joint-noise", 0.01,
                       "--drop-frac", 0.1)  # fmt: skip
    assert code == 0, err
    a, b = load_motion(src), load_motion(out)
    assert np.array_equal(a.pose_body, b.pose_body)
    assert 0.005 < (b.trans - a.trans).std() < 0.015
    assert b.joint_mask.shape == (50, 22) and int((~b.joint_mask).sum()) == 110
    # spikes: only some body-joint entries move, by about --spike-rad
    code, _, err = run("add-noise", src, "-o", tmp_path / "s.npz", "--sigma", 0,
                       "--spike-frac", 0.2, "--spike-rad", 0.5)  # fmt: skip
    assert code == 0, err
    s = load_motion(tmp_path / "s.npz")
    moved = np.any(s.pose_body != a.pose_body, axis=-1)
    assert 0.1 < moved.mean() < 0.3 and 0.3 < (s.pose_body - a.pose_body)[moved].std() < 0.7
    assert np.array_equal(s.root_orient, a.root_orient) and np.array_equal(s.trans, a.trans)


def test_add_noise_refuses_to_overwrite_input(make_motion_file, tmp_path, hash_tree):
    src = make_motion_file("c.npz", T=5)
    before = hash_tree(tmp_path)
    line = assert_one_error_line(*run("add-noise", src, "-o", src))
    assert "overwrite" in line
    assert hash_tree(tmp_path) == before
    # a folder mirrored onto itself is refused up front
    assert_one_error_line(*run("add-noise", tmp_path, "-o", tmp_path))
    assert hash_tree(tmp_path) == before


def test_add_noise_folder_into_npz_name_is_refused(make_motion_file, tmp_path):
    make_motion_file("in/a.npz", T=3)
    line = assert_one_error_line(*run("add-noise", tmp_path / "in", "-o", tmp_path / "x.npz"))
    assert "must be a folder" in line and not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize("command", ["add-noise", "denoise", "import"])
def test_an_output_named_as_a_pickle_is_refused_not_made_a_folder(
    make_motion_file, tmp_path, command
):
    src = make_motion_file("in/a.npz", T=12)
    for name in ("clean.pkl", "clean.pt.gz"):
        line = assert_one_error_line(*run(command, src, "-o", tmp_path / name))
        assert "clean.npz" in line and not (tmp_path / name).exists(), line
    (tmp_path / "out.pkl").mkdir()  # an existing folder of that name is a folder
    code, _, err = run(command, src, "-o", tmp_path / "out.pkl")
    assert code == 0 and (tmp_path / "out.pkl" / "a.npz").is_file(), err


def test_add_noise_batch_goes_on_after_a_failure(make_motion_file, tmp_path):
    make_motion_file("in/a.npz", T=5)
    make_motion_file("in/b.npz", T=5, poses=None)  # broken
    make_motion_file("in/c.npz", T=5)
    code, out, err = run("add-noise", tmp_path / "in", "-o", tmp_path / "out", "--json")
    assert code == 1
    assert "Traceback" not in err
    assert sum(line.startswith("error: ") for line in err.splitlines()) == 1
    assert "b.npz" in err
    assert (tmp_path / "out" / "a.npz").exists() and (tmp_path / "out" / "c.npz").exists()
    assert not (tmp_path / "out" / "b.npz").exists()
    data = json.loads(out)
    assert data["failed"] == 1 and data["succeeded"] == 2
    assert [f["ok"] for f in data["files"]] == [True, False, True]


@pytest.mark.parametrize(
    "option",
    [("--sigma", -1), ("--drop-frac", 2), ("--joint-noise", -0.1), ("--spike-frac", 2),
     ("--spike-rad", -1)],
)  # fmt: skip
def test_add_noise_bad_option_values(make_motion_file, tmp_path, option):
    # refused while parsing (one error line, exit 1) naming the option; nothing written
    src = make_motion_file("c.npz", T=5)
    code, out, err = run("add-noise", src, "-o", tmp_path / "n.npz", *option)
    assert code == 1 and f"Invalid value for '{option[0]}'" in out + err
    assert "Traceback" not in out + err and not (tmp_path / "n.npz").exists()


# --- export-mesh -------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt, every, expected", [("ply", 1, 5), ("obj", 2, 3)])
def test_export_mesh_writes_one_file_per_frame(make_motion_file, tmp_path, fmt, every, expected):
    import trimesh

    src = make_motion_file("m.npz", T=5)
    out = tmp_path / "meshes"
    code, _, err = run("export-mesh", src, "--out", out, "--format", fmt, "--every", every)
    assert code == 0, err
    files = sorted(p.name for p in out.iterdir())
    assert files == [f"frame_{i:06d}.{fmt}" for i in range(0, 5, every)]
    assert f"wrote {len(files)} {fmt} meshes to {out}" in " ".join(err.split())
    mesh = trimesh.load(out / files[-1], force="mesh", process=False)
    assert len(mesh.vertices) > 0 and len(mesh.faces) > 0


def test_export_mesh_folder_mirrors(make_motion_file, tmp_path):
    make_motion_file("in/x.npz", T=2)
    make_motion_file("in/d/y.npz", T=3)
    code, _, err = run("export-mesh", tmp_path / "in", "-o", tmp_path / "out")
    assert code == 0, err
    assert len(list((tmp_path / "out" / "x").glob("*.ply"))) == 2
    assert len(list((tmp_path / "out" / "d" / "y").glob("*.ply"))) == 3


# --- bad input: every command, one error line, non-zero exit, input untouched --------------------


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def bad_input(kind: str, tmp_path: Path, make_motion_file) -> Path:
    """A broken motion file of the given kind (or a path that does not exist)."""
    if kind == "missing file":
        return tmp_path / "nope.npz"
    if kind == "not an npz":
        return _write(tmp_path / "text.npz", b"this is not a zip archive\n")
    if kind == "bare npy":
        path = tmp_path / "bare.npz"
        with open(path, "wb") as fh:
            np.save(fh, np.zeros((4, 156)))
        return path
    if kind in ("truncated npz", "corrupt npz"):
        good = make_motion_file("good_source.npz", T=10).read_bytes()
        if kind == "truncated npz":
            return _write(tmp_path / "trunc.npz", good[: len(good) // 2])
        middle = len(good) // 3  # inside the 'poses' member data: CRC check fails
        garbled = good[:middle] + bytes(b ^ 0xFF for b in good[middle : middle + 64])
        return _write(tmp_path / "corrupt.npz", garbled + good[middle + 64 :])
    arrays = {
        "missing poses": {"poses": None},
        "wrong width": {"poses": np.zeros((10, 50))},
        "1-D poses": {"poses": np.zeros(156)},
        "NaN": {"poses": np.full((10, 156), np.nan)},
        "inf in trans": {"trans": np.full((10, 3), np.inf)},
        "0 frames": {"poses": np.zeros((0, 156)), "trans": np.zeros((0, 3))},
        "fps 0": {"mocap_framerate": 0.0},
        "fps negative": {"mocap_framerate": -30.0},
        "no fps": {"mocap_framerate": None},
        "pickled": {"gender": np.array([{"x": 1}], dtype=object)},
    }[kind]
    return make_motion_file(f"bad_{kind.replace(' ', '_')}.npz", T=10, **arrays)


BAD_KINDS = [
    "missing file", "not an npz", "bare npy", "truncated npz", "corrupt npz", "missing poses",
    "wrong width", "1-D poses", "NaN", "inf in trans", "0 frames", "fps 0",
    "fps negative", "no fps", "pickled",
]  # fmt: skip


def command_for(name: str, bad: Path, good: Path, tmp_path: Path) -> list:
    return {
        "add-noise": ["add-noise", bad, "-o", tmp_path / "out.npz"],
        "eval-gt": ["eval", "--gt", bad, "--pred", good],
        "eval-pred": ["eval", "--gt", good, "--pred", bad, "--json"],
        "export-mesh": ["export-mesh", bad, "--out", tmp_path / "meshes"],
    }[name]


@pytest.mark.parametrize("kind", BAD_KINDS)
@pytest.mark.parametrize("command", ["add-noise", "eval-gt", "eval-pred", "export-mesh"])
def test_bad_input_gives_one_error_line(
    small_default_body, make_motion_file, tmp_path, hash_tree, command, kind
):
    bad = bad_input(kind, tmp_path, make_motion_file)
    good = make_motion_file("good.npz", T=10)
    before = hash_tree(tmp_path)
    code, out, err = run(*command_for(command, bad, good, tmp_path))
    if command == "eval-pred":
        # --json: a per-file failure is also in the JSON document on stdout, and so is an
        # error before any file is read
        doc = json.loads(out)
        refused = {"ok": False, "error": doc.get("error"), "exit_code": 1}
        assert code == 1 and (doc == refused if kind == "missing file" else doc["failed"] == 1)
        out = ""
    line = assert_one_error_line(code, out, err)
    assert bad.name in line
    assert hash_tree(tmp_path) == before  # nothing written, nothing changed
    assert not (tmp_path / "out.npz").exists() and not (tmp_path / "meshes").exists()


@pytest.mark.parametrize("command", ["eval", "export-mesh"])
@pytest.mark.parametrize("content", [b"", b"garbage bytes", None])
def test_unreadable_body_model(make_motion_file, tmp_path, command, content):
    good = make_motion_file("good.npz", T=4)
    model = tmp_path / "model.npz"
    if content is not None:
        model.write_bytes(content)
    args = {
        "eval": ["eval", "--gt", good, "--pred", good],
        "export-mesh": ["export-mesh", good, "--out", tmp_path / "meshes"],
    }[command]
    assert_one_error_line(*run(*args, "--body-model", model))
    assert not (tmp_path / "meshes").exists()


def test_export_mesh_sequence_library(tiny_body, tmp_path):
    import torch
    import trimesh
    from conftest import motion_arrays

    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.errors import InputError
    from mdvae_cli.export import export_mesh_sequence
    from mdvae_cli.formats.npz_io import motion_from_arrays

    m = motion_from_arrays(motion_arrays(T=7))
    calls = []
    paths = export_mesh_sequence(m, tiny_body, tmp_path / "o", "ply", every=3, chunk_frames=2,
                                 progress=calls.append)  # fmt: skip
    assert [p.name for p in paths] == ["frame_000000.ply", "frame_000003.ply", "frame_000006.ply"]
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [p.name for p in paths]
    assert sum(calls) == 3
    f = lambda a: torch.as_tensor(a)  # noqa: E731
    ref = BodyModel(tiny_body, dtype=torch.float64)(
        f(m.root_orient[3:4]), f(m.pose_body[3:4]), f(m.trans[3:4]), f(m.betas), vertices=True
    )
    mesh = trimesh.load(paths[1], force="mesh", process=False)
    assert np.allclose(mesh.vertices, ref.vertices[0].numpy(), atol=1e-5)
    assert np.array_equal(mesh.faces, tiny_body.faces)
    with pytest.raises(InputError):
        export_mesh_sequence(m, tiny_body, tmp_path / "o", "stl")
    with pytest.raises(InputError):
        export_mesh_sequence(m, tiny_body, tmp_path / "o", "ply", every=0)
    with pytest.raises(InputError):
        export_mesh_sequence(m, tiny_body, paths[0], "ply")  # a file, not a folder
    # a shorter take exported into the same folder: the earlier take's tail is removed, other
    # files (another format, the user's own) are left alone
    (tmp_path / "o" / "notes.txt").write_text("mine")
    (tmp_path / "o" / "frame_000099.obj").write_text("another format")
    (tmp_path / "o" / "frame_12.ply").write_text("not our naming")
    short = motion_from_arrays(motion_arrays(T=2))
    again = export_mesh_sequence(short, tiny_body, tmp_path / "o", "ply")
    assert [p.name for p in again] == ["frame_000000.ply", "frame_000001.ply"]
    left = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert left == [
        "frame_000000.ply",
        "frame_000001.ply",
        "frame_000099.obj",
        "frame_12.ply",
        "notes.txt",
    ]


def test_process_seconds_counts_from_the_process_start(monkeypatch):
    """The summary's seconds: since the process started (start-up and imports included, which
    a command's own clock misses), read from /proc; since the command began where /proc is not
    there or its clocks disagree with ours (a container's uptime, a process far older than a
    command's start-up)."""
    import builtins
    import io
    import os
    import time

    from mdvae_cli.cli.common import STARTUP_LIMIT_S, process_seconds

    tick = os.sysconf("SC_CLK_TCK")
    start_ticks = 9_850 * tick // 100  # the process started 98.5 s after boot
    real_open = builtins.open

    def fake_proc(uptime: float | None):
        def fake(path, *args, **kwargs):
            if str(path).startswith("/proc"):
                if uptime is None:
                    raise FileNotFoundError(path)
                if str(path) == "/proc/uptime":
                    return io.StringIO(f"{uptime:.2f} 1.0\n")
                return io.StringIO(f"123 (python3 (x)) S {' '.join(['0'] * 18)} {start_ticks} 0\n")
            return real_open(path, *args, **kwargs)

        return fake

    began = time.perf_counter()
    monkeypatch.setattr(builtins, "open", fake_proc(100.0))  # 1.5 s after the start
    assert abs(process_seconds(began) - 1.5) < 1e-6
    for uptime in (1.0, 98.5 + STARTUP_LIMIT_S + 10, None):  # before it, far after, no /proc
        monkeypatch.setattr(builtins, "open", fake_proc(uptime))
        assert 0 <= process_seconds(began) <= time.perf_counter() - began
    monkeypatch.undo()
    # this process, on this system: at least the time since ``began``
    assert process_seconds(began) >= time.perf_counter() - began - 0.02


def test_the_summary_seconds_leave_out_what_a_shell_did_before_it_ran_the_command():
    """A shell runs the last command of ``bash -c`` (or of ``( ... )``) in its own process,
    which /proc dates from the shell's start: ``(pip install ... && mdvae denoise ...)`` read
    the install's 25 s as the command's. Past :data:`STARTUP_LIMIT_S` the command's own clock
    is taken."""
    import shlex
    import shutil
    import subprocess
    import sys

    from mdvae_cli.cli.common import STARTUP_LIMIT_S

    if shutil.which("bash") is None or not Path("/proc/self/stat").exists():
        pytest.skip("needs bash and /proc")
    code = (
        "import time; t = time.perf_counter(); "
        "from mdvae_cli.cli.common import process_seconds; print(process_seconds(t))"
    )
    assert STARTUP_LIMIT_S < 3.0
    script = f"sleep 3; exec {shlex.quote(sys.executable)} -c {shlex.quote(code)}"
    out = subprocess.run(["bash", "-c", script], capture_output=True, text=True, check=True)
    assert float(out.stdout) < 1.0  # the command's own time, not the shell's sleep too
