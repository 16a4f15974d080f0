"""What a demanding user runs into: option values that are not numbers, options that need
another, outputs that would clash or land on folders, results that must never be written."""

from __future__ import annotations

import errno
import inspect
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import expand_inputs, write_atomic
from mdvae_cli.formats.npz_io import load_motion

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NOISY = EXAMPLES / "noisy_walk.npz"


def invoke(*args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception
    return res


def one_error_line(res) -> str:
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.mark.parametrize(
    "args, message",
    [
        (["denoise", NOISY, "--refine", "5", "--refine-lr", "inf"], "'inf' is not a finite number"),
        (["denoise", NOISY, "--refine-offset", "nan"], "'nan' is not a finite number"),
        (["denoise", NOISY, "--optimize", "1", "--lr", "0"], "0 is not > 0"),
        (["add-noise", NOISY, "--sigma", "nan"], "'nan' is not a finite number"),
        (["add-noise", NOISY, "--sigma", "-0.1"], "-0.1 is not >= 0"),
        (["add-noise", NOISY, "--drop-frac", "2"], "2 is not <= 1"),
        (["add-noise", NOISY, "--joint-noise", "abc"], "'abc' is not a number"),
        (["sample", "--from", NOISY, "--temperature", "nan"], "'nan' is not a finite number"),
        (["sample", "--from", NOISY, "--speed-limit", "inf"], "'inf' is not a finite number"),
        (["import", NOISY, "--fps", "inf"], "'inf' is not a finite number"),
        (["sample", "--from", NOISY, "--seed", str(2**64)], "is not in the range 0<=x<="),
        (["denoise", NOISY, "--optimize", "1", "--seed", "-1"], "is not in the range 0<=x<="),
    ],
)
def test_numbers_that_are_not_finite_or_in_range_are_usage_errors(tmp_path, args, message):
    out = tmp_path / "o.npz"
    res = invoke(*args, "-o", out)
    assert res.exit_code == 1 and message in res.output and "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")  # not Click's usage block
    assert not out.exists()


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--per-file"], "--per-file only applies with --optimize N"),
        (["--lr", "0.001"], "--lr only applies with --optimize N"),
        (["--mesh-format", "obj"], "--mesh-format only applies with --mesh-dir DIR"),
    ],
)
def test_denoise_options_that_need_another_say_so(tmp_path, extra, message):
    out = tmp_path / "o.npz"
    line = one_error_line(invoke("denoise", NOISY, "-o", out, *extra))
    assert message in line and not out.exists()


def test_denoise_mesh_dir_that_is_a_file_writes_nothing(tmp_path):
    blocker = tmp_path / "meshes"
    blocker.write_text("a file")
    out = tmp_path / "o.npz"
    line = one_error_line(invoke("denoise", NOISY, "-o", out, "--mesh-dir", blocker))
    assert "is a file; give a folder" in line and not out.exists()


def test_two_inputs_with_one_output_name_are_refused_before_any_work(tmp_path):
    for sub in ("cA", "cB"):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "take.npz").write_bytes(NOISY.read_bytes())
    coll = tmp_path / "coll"
    res = invoke("add-noise", tmp_path / "cA", tmp_path / "cB", "-o", coll)
    line = one_error_line(res)
    assert "would both be written to" in line and "take.npz" in line
    assert not coll.exists()
    # the same files named one by one clash too; their common parent is fine
    res = invoke("add-noise", tmp_path / "cA/take.npz", tmp_path / "cB/take.npz", "-o", coll)
    one_error_line(res)
    res = invoke("add-noise", tmp_path / "cA", tmp_path / "cB", "-o", coll, "--sigma", "0")
    assert res.exit_code == 1 and not coll.exists()
    parent = tmp_path / "both"
    parent.mkdir()
    for sub in ("cA", "cB"):
        (tmp_path / sub).rename(parent / sub)
    res = invoke("add-noise", parent, "-o", coll)
    assert res.exit_code == 0, res.output
    assert sorted(p.relative_to(coll).as_posix() for p in coll.rglob("*.npz")) == [
        "cA/take.npz",
        "cB/take.npz",
    ]


def test_denoise_summary_counts_files_that_could_not_be_read(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    (src / "walk.npz").write_bytes(NOISY.read_bytes())
    (src / "bad1.npz").write_text("not a zip")
    (src / "bad2.npz").write_text("not a zip either")
    res = invoke("denoise", src, "-o", tmp_path / "out")
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "denoise: 1 of 3 files done, 2 failed" in " ".join(res.output.split())
    assert sorted(p.name for p in (tmp_path / "out").glob("*.npz")) == ["walk.npz"]


def test_summary_and_notes_are_one_line_each_however_narrow_the_output(tmp_path):
    """A pipeline's log is read line by line: a narrow terminal or pipe (COLUMNS=40) breaks
    no message in two (the summary line is longer than 100 characters)."""
    res = CliRunner().invoke(cli, ["denoise", str(NOISY), "-o", str(tmp_path / "c.npz")],
                             env={"COLUMNS": "40"})  # fmt: skip
    assert res.exit_code == 0, res.output
    summary = [ln for ln in res.output.splitlines() if ln.startswith("denoised ")]
    assert len(summary) == 1 and len(summary[0]) > 100, res.output
    assert summary[0].rstrip().endswith("%")  # the share kept, on the same line


def test_a_result_that_is_not_finite_is_never_written(tmp_path, monkeypatch):
    from mdvae_cli.infer import denoise as denoise_module

    def diverged(motions, *args, **kwargs):
        m = motions[0]
        return [m.with_body(pose_body=np.full_like(m.pose_body, np.nan))]

    monkeypatch.setattr(denoise_module, "denoise_motions", diverged)
    out = tmp_path / "o.npz"
    line = one_error_line(invoke("denoise", NOISY, "-o", out))
    assert "pose_body is not finite" in line and not out.exists()


def test_writing_onto_a_folder_or_below_a_file_is_one_clear_error(tmp_path):
    folder = tmp_path / "existing"
    folder.mkdir()
    with pytest.raises(InputError, match="it is a folder"):
        write_atomic(folder, lambda tmp: tmp.write_bytes(b"x"))
    a_file = tmp_path / "walk.npz"
    a_file.write_bytes(b"x")
    with pytest.raises(InputError, match="walk.npz is a file, not a folder"):
        write_atomic(a_file / "o.npz", lambda tmp: tmp.write_bytes(b"x"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing", "walk.npz"]
    # sample's output is one file: a folder (trailing slash) is refused in one line
    line = one_error_line(invoke("sample", "--from", NOISY, "-o", str(folder) + "/"))
    assert "is a folder; give the output .npz file's name" in line


def test_folders_yield_upper_case_suffixes_and_skip_hidden_folders(tmp_path):
    (tmp_path / "A.NPZ").write_bytes(b"x")
    (tmp_path / "b.npz.gz").write_bytes(b"x")
    (tmp_path / ".cache").mkdir()
    (tmp_path / ".cache" / "c.npz").write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("x")
    found = sorted(rel.as_posix() for _, rel in expand_inputs([tmp_path]))
    assert found == ["A.NPZ", "b.npz.gz"]


def test_a_file_without_checkpoint_metadata_is_named_as_such(tmp_path):
    from mdvae_cli.model.checkpoint import load_checkpoint

    with pytest.raises(InputError, match="is not an mdvae checkpoint"):
        load_checkpoint(NOISY)
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(tmp_path / "missing.npz")


@pytest.mark.parametrize("columns", [None, "80", "60"])
def test_eval_table_is_not_cut_off_a_terminal(columns):
    args = ["eval", "--gt", str(EXAMPLES / "walk.npz"), "--pred", str(NOISY)]
    res = CliRunner().invoke(cli, args, env={"COLUMNS": columns})
    assert res.exit_code == 0, res.output
    assert "acc err" in res.output and "MPJPE world" in res.output and "…" not in res.output
    widest = max(len(line) for line in res.output.splitlines())
    if columns is None:  # logs and pipes get the one-row-per-file table
        assert widest > 80
    else:  # COLUMNS=80 mdvae eval ...: a column per file, every metric whole
        assert widest <= int(columns) and "665.82 (6.50)" in res.output


def test_sample_does_not_claim_the_start_file_s_source_or_duration(tmp_path):
    with np.load(EXAMPLES / "walk.npz") as z:
        arrays = dict(z)
    start = tmp_path / "walk.npz"
    np.savez(start, **arrays, mocap_time_length=np.array(79 / 30.0))
    out = tmp_path / "s.npz"
    res = invoke("sample", "--from", start, "--frames", "3", "--particles", "1", "-o", out)
    assert res.exit_code == 0, res.output
    with np.load(out) as z:
        assert str(z["source"]) == "mdvae sample from the first frame of walk.npz"
        assert float(z["mocap_time_length"]) == 0.1  # 3 frames at 30 Hz


def test_a_one_frame_file_is_a_pose_every_command_but_denoise_takes(tmp_path):
    with np.load(EXAMPLES / "walk.npz") as z:
        arrays = dict(z)
    one = tmp_path / "pose.npz"
    np.savez(one, **{**arrays, "poses": arrays["poses"][:1], "trans": arrays["trans"][:1]})
    assert invoke("eval", "--gt", one, "--pred", one).exit_code == 0
    res = invoke("export-mesh", one, "-o", tmp_path / "mesh")
    assert res.exit_code == 0 and len(list((tmp_path / "mesh").glob("*.ply"))) == 1
    res = invoke(
        "sample", "--from", one, "--frames", "4", "--particles", "1", "-o", tmp_path / "s.npz"
    )
    assert res.exit_code == 0 and np.load(tmp_path / "s.npz")["poses"].shape[0] == 4
    line = one_error_line(invoke("denoise", one, "-o", tmp_path / "d.npz"))
    assert "too short to denoise" in line and "(6 frames at 30 Hz)" in line


def test_a_file_named_twice_counts_once(tmp_path):
    (tmp_path / "a.npz").write_bytes(b"x")
    found = expand_inputs([tmp_path / "a.npz", tmp_path, tmp_path / "a.npz"])
    assert [rel.as_posix() for _, rel in found] == ["a.npz"]
    out = tmp_path / "o"
    res = invoke("add-noise", NOISY, NOISY, "-o", out)
    assert res.exit_code == 0, res.output
    assert [p.name for p in out.iterdir()] == ["noisy_walk.npz"]


def test_import_of_a_skeleton_alone_says_what_is_missing(tmp_path):
    asf = tmp_path / "07.asf"
    asf.write_text(":version 1.10\n")
    line = one_error_line(invoke("import", asf, "-o", tmp_path / "out"))
    assert "is a skeleton only: give the .amc motions too" in line


def test_an_interrupt_at_any_moment_of_a_write_leaves_no_temporary(tmp_path):
    """Ctrl-C lands between any two Python lines of write_atomic (or of what it calls): the
    folder then holds the old file or the complete new one, never a temporary beside it."""
    target = tmp_path / "o.npz"
    interrupted_at, previous = [], sys.gettrace()  # e.g. a coverage tracer, given back after
    for n in range(1, 5000):
        target.write_bytes(b"old")
        left = n

        def tracer(frame, event, arg):
            nonlocal left
            if frame.f_code.co_flags & inspect.CO_GENERATOR:
                return None  # an exception while a generator is closed is only "ignored"
            left -= event == "line"
            if left == 0:
                raise KeyboardInterrupt  # as a signal handler would, here; unsets the tracer
            return tracer

        sys.settrace(tracer)
        try:
            write_atomic(target, lambda tmp: tmp.write_bytes(b"new"))
        except KeyboardInterrupt:
            interrupted_at.append(n)
        finally:
            sys.settrace(previous)
        assert [p.name for p in tmp_path.iterdir()] == ["o.npz"], n
        assert target.read_bytes() in (b"old", b"new")
        if left > 0:  # the write ran to its end before the n-th event
            break
    assert len(interrupted_at) > 20 and target.read_bytes() == b"new"


def test_a_failing_file_system_is_one_line_naming_the_output(tmp_path, monkeypatch):
    def no_space(tmp):
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))

    with pytest.raises(InputError, match=r"^cannot write .*o\.npz: No space left on device$"):
        write_atomic(tmp_path / "o.npz", no_space)
    assert list(tmp_path.iterdir()) == []

    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    line = one_error_line(invoke("add-noise", NOISY, "-o", tmp_path / "sub" / "o.npz"))
    assert line.endswith(
        "cannot write " + str(tmp_path / "sub" / "o.npz") + ": Read-only file system"
    )


def test_an_output_folder_inside_the_input_folder_is_not_read_back(tmp_path):
    src = tmp_path / "takes"
    src.mkdir()
    (src / "walk.npz").write_bytes(NOISY.read_bytes())
    for _ in range(2):  # the second run must not take the first one's output as an input
        res = invoke("add-noise", src, "-o", src / "noisy", "--json")
        assert res.exit_code == 0, res.output
    assert sorted(p.relative_to(src).as_posix() for p in src.rglob("*.npz")) == [
        "noisy/walk.npz",
        "walk.npz",
    ]
    # an input folder inside the output folder is still read
    res = invoke("add-noise", src / "noisy", "-o", tmp_path)
    assert res.exit_code == 0 and (tmp_path / "walk.npz").exists()


def test_sigma_minus_zero_is_zero(tmp_path):
    out = tmp_path / "o.npz"
    assert invoke("add-noise", EXAMPLES / "walk.npz", "-o", out, "--sigma", "-0").exit_code == 0
    with np.load(out) as z, np.load(EXAMPLES / "walk.npz") as ref:
        np.testing.assert_array_equal(z["poses"], ref["poses"])


def test_values_too_large_for_the_file_s_dtype_are_never_written(tmp_path):
    out = tmp_path / "o.npz"  # walk.npz holds float32 poses: 1e308 rad noise overflows them
    line = one_error_line(invoke("add-noise", EXAMPLES / "walk.npz", "-o", out, "--sigma", "1e308"))
    # refused before the file's dtype is reached: the motion itself holds infinities
    assert "a body-joint rotation holds NaN or infinite values" in line
    assert "nothing written" in line
    assert list(tmp_path.iterdir()) == []


def test_an_output_name_in_upper_case_is_a_file_as_an_input_s_would_be(tmp_path):
    out = tmp_path / "CLEAN.NPZ"
    assert invoke("add-noise", NOISY, "-o", out).exit_code == 0
    assert out.is_file() and np.load(out)["poses"].shape == (79, 156)
    line = one_error_line(
        invoke("add-noise", NOISY, EXAMPLES / "walk.npz", "-o", tmp_path / "B.Npz")
    )
    assert "must be a folder" in line and not (tmp_path / "B.Npz").exists()


def test_an_implausible_frame_rate_is_refused_when_the_file_is_read(tmp_path):
    """A frame time stored as the rate (1/120) made 30 frames into an hour of motion; rates
    such as 1e-9 or 1e-300 ended in MemoryError/OverflowError text. 1 and 10,000 Hz are read."""
    with np.load(EXAMPLES / "walk.npz") as z:
        arrays = dict(z)
    for rate, message in [
        (1 / 120, "frame rate 0.00833333 Hz is implausible (1 to 10000 Hz); is mocap_framerate "
         "a frame time? (1/0.00833333 = 120 Hz)"),
        (1e-9, "frame rate 1e-09 Hz is implausible (1 to 10000 Hz)"),
        (1e-300, "frame rate 1e-300 Hz is implausible (1 to 10000 Hz)"),
        (10_001.0, "frame rate 10001 Hz is implausible (1 to 10000 Hz)"),
    ]:  # fmt: skip
        src = tmp_path / "take.npz"
        np.savez(src, **{**arrays, "mocap_framerate": np.array(rate)})
        with pytest.raises(InputError) as info:
            load_motion(src)
        assert str(info.value) == f"{src}: {message}"
        line = one_error_line(invoke("add-noise", src, "-o", tmp_path / "o.npz"))
        assert line.endswith(message) and not (tmp_path / "o.npz").exists()
    for rate in (1.0, 10_000.0):
        np.savez(src, **{**arrays, "mocap_framerate": np.array(rate)})
        assert load_motion(src).fps == rate


def test_an_output_that_is_an_input_is_refused_before_anything_is_read(tmp_path, monkeypatch):
    import mdvae_cli.formats.npz_io as npz_io

    def never(*args, **kwargs):
        raise AssertionError("an input was read")

    monkeypatch.setattr(npz_io, "load_motion", never)
    folder = tmp_path / "takes"
    folder.mkdir()
    for name in ("a.npz", "b.npz"):
        (folder / name).write_bytes(NOISY.read_bytes())
    a = folder / "a.npz"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    for args in [
        ("denoise", a, "-o", a, "--optimize", "50"),
        ("denoise", a, "-o", folder / "." / "a.npz"),  # the same file by another name
        ("denoise", a, folder / "b.npz", "-o", folder),  # mirrored onto themselves
        ("add-noise", a, "-o", a),
        ("export-mesh", a, "-o", a),
        ("sample", "--from", a, "-o", a),
    ]:
        line = one_error_line(invoke(*args))
        assert line.startswith("error: refusing to overwrite the input file "), args
        assert line.endswith(": choose another -o") and "a.npz" in line, args
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_output_names_mean_what_they_say(tmp_path):
    # a trailing slash is a folder, even when the name ends in .npz
    res = invoke("add-noise", NOISY, "-o", str(tmp_path / "new.npz") + "/")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "new.npz").is_dir() and (tmp_path / "new.npz/noisy_walk.npz").is_file()
    # mdvae writes .npz: a .gz name is refused, not made a folder (nor a file no reader takes)
    for name, fix in (("x.npz.gz", "x.npz"), ("y.GZ", "y.npz")):
        line = one_error_line(invoke("add-noise", NOISY, "-o", tmp_path / name))
        assert line.endswith(f"mdvae writes .npz, not .gz: name the output {tmp_path / fix}")
        line = one_error_line(invoke("sample", "--from", NOISY, "-o", tmp_path / name))
        assert line.endswith(f"mdvae writes .npz, not .gz: name the output {tmp_path / fix}")
    # an existing file that is not .npz, for one input
    notes = tmp_path / "existing.txt"
    notes.write_text("keep")
    line = one_error_line(invoke("add-noise", NOISY, "-o", notes))
    assert (
        line
        == f"error: the output {notes} is a file that is not .npz: name an .npz file or a folder"
    )
    assert notes.read_text() == "keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.txt", "new.npz"]
    # a name with another file kind's suffix is refused, not made a folder holding the take
    for command in ("add-noise", "denoise"):
        line = one_error_line(invoke(command, NOISY, "-o", tmp_path / "clean.txt"))
        assert line.endswith(
            f"cannot write {tmp_path / 'clean.txt'}: .txt is not a motion file mdvae writes; "
            "name an .npz (any input), a .bvh or .amc (a take of that form) or the input's own "
            "form, or end the name with / for a folder"
        ), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.txt", "new.npz"]
    for command, wanted in (("export-bvh", ".bvh"), ("import", ".npz")):
        line = one_error_line(invoke(command, NOISY, "-o", tmp_path / "m.txt"))
        assert line.endswith(
            f"cannot write {tmp_path / 'm.txt'}: .txt is not a motion file mdvae writes; name a "
            f"file ending in {wanted}, or end the name with / for a folder"
        ), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.txt", "new.npz"]
    # a dotted name that is no file kind (digits) is a folder as before
    res = invoke("add-noise", NOISY, "-o", tmp_path / "run.v2")
    assert res.exit_code == 0 and (tmp_path / "run.v2" / "noisy_walk.npz").is_file()


def test_denoise_mesh_subfolders_are_named_as_export_mesh_names_them(tmp_path):
    """A gzipped take's meshes go to a subfolder without .npz.gz (take.npz.gz -> take/), as
    `mdvae export-mesh` names it, beside its cleaned .npz."""
    import gzip

    src = tmp_path / "in"
    src.mkdir()
    (src / "b.npz").write_bytes(NOISY.read_bytes())
    with gzip.open(src / "a.npz.gz", "wb") as fh:
        fh.write(NOISY.read_bytes())
    res = invoke("denoise", src, "-o", tmp_path / "out", "--mesh-dir", tmp_path / "mesh")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "mesh").iterdir()) == ["a", "b"]
    frames = load_motion(NOISY).num_frames
    assert len(list((tmp_path / "mesh" / "a").glob("frame_*.ply"))) == frames
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.npz", "b.npz"]


def test_the_console_script_ends_at_once_with_the_commands_code_and_output(tmp_path):
    """``mdvae`` (``cli.main.main``) ends without tearing torch down, a quarter of a second a
    command: its output is all there in a pipe, exit handlers run, and the code is the
    command's (0, a refusal's 1, Click's bad usage 1 too)."""
    import subprocess

    prelude = (
        "import atexit, sys\n"
        "atexit.register(lambda: print('handlers ran', file=sys.stderr))\n"
        "from mdvae_cli.cli.main import main\n"
        "sys.argv = ['mdvae'] + sys.argv[1:]\n"
        "main()\n"
        "print('not reached')\n"
    )

    def console(*args):
        return subprocess.run([sys.executable, "-c", prelude, *args], capture_output=True,
                              text=True, timeout=300)  # fmt: skip

    done = console("--version")
    assert done.returncode == 0 and done.stdout.startswith("mdvae, version")
    assert "not reached" not in done.stdout and "handlers ran" in done.stderr
    refused = console("denoise", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "o.npz"))
    assert refused.returncode == 1 and "handlers ran" in refused.stderr
    assert refused.stderr.startswith("error: ") and "Traceback" not in refused.stderr
    assert console("denoise", "--no-such-option").returncode == 1
    script = Path(__file__).resolve().parents[1] / "pyproject.toml"
    assert 'mdvae = "mdvae_cli.cli.main:main"' in script.read_text()
