"""A take's file read in a child process while torch loads (``run.read_ahead``): the value
handed over is the one the call makes here, a failing child leaves the call to this process,
and ``mdvae denoise`` on a BVH writes the same bytes with and without it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.formats.registry import write
from mdvae_cli.run import read_ahead
from mdvae_cli.run.read_ahead import ReadAhead, can_fork

REPO = Path(__file__).resolve().parents[1]
NOISY = REPO / "examples" / "noisy_walk.npz"
needs_fork = pytest.mark.skipif(
    not hasattr(os, "fork") or sys.platform == "darwin" or len(os.sched_getaffinity(0)) < 2,
    reason="a read goes ahead in a forked child, on two cores",
)


def fresh_python(code: str, *args: str, cores: set[int] | None = None) -> str:
    """Run ``code`` in a new interpreter (no torch loaded, no thread), on ``cores`` if given
    -> its standard output."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        capture_output=True, text=True, env=env, check=False,
        preexec_fn=None if cores is None else (lambda: os.sched_setaffinity(0, cores)),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture
def take(tmp_path) -> Path:
    path = tmp_path / "walk.bvh"
    write(load_motion(NOISY), path)
    return path


def test_no_read_ahead_once_torch_is_loaded():
    import torch  # noqa: F401 - what a test process has

    assert not can_fork()
    ahead = ReadAhead()
    assert not ahead.start(len, "abc") and len(ahead) == 0
    assert ahead.call(len, "abc") == 3


@needs_fork
def test_the_childs_value_is_the_call_made_here(take):
    out = fresh_python(
        """
        import os, sys
        import numpy as np
        from pathlib import Path
        from mdvae_cli.retarget.source_file import load_source
        from mdvae_cli.run.read_ahead import ReadAhead

        path = Path(sys.argv[1])
        ahead = ReadAhead()
        assert ahead.start(load_source, path, None, fps=None, scale=None, joint_map=None)
        assert ahead.start(load_source, path, None, fps=60.0, scale=None, joint_map=None)
        assert "torch" not in sys.modules
        (_, child, _), (_, other, _) = ahead.children
        src = ahead.call(load_source, path, None, fps=None, scale=None, joint_map=None)
        here = load_source(path, None, fps=None, scale=None, joint_map=None)
        assert "torch" not in sys.modules  # a take is read with numpy alone
        np.testing.assert_array_equal(src.layout.data, here.layout.data)
        np.testing.assert_array_equal(src.rotations, here.rotations)
        np.testing.assert_array_equal(src.root_positions, here.root_positions)
        said = lambda s: (s.fps, s.names, s.info, s.notes)
        assert said(src) == said(here)
        assert len(ahead) == 1  # the other call's child
        at60 = ahead.call(load_source, path, None, fps=60.0, scale=None, joint_map=None)
        assert at60.fps == 60.0 and src.fps == 30.0 and len(ahead) == 0
        for pid in (child, other):
            try:
                os.waitpid(pid, 0)
            except ChildProcessError:
                print("reaped")
        """,
        str(take),
    )
    assert out.split() == ["reaped", "reaped"]


@needs_fork
def test_a_failing_child_leaves_the_call_and_its_error_here(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    out = fresh_python(
        """
        import sys
        from pathlib import Path
        from mdvae_cli.errors import InputError
        from mdvae_cli.retarget.source_file import load_source
        from mdvae_cli.run.read_ahead import ReadAhead

        path = Path(sys.argv[1])
        ahead = ReadAhead()
        ahead.start(load_source, path, None, fps=None, scale=None, joint_map=None)
        try:
            load_source(path, None, fps=None, scale=None, joint_map=None)
        except InputError as exc:
            direct = str(exc)
        try:
            ahead.call(load_source, path, None, fps=None, scale=None, joint_map=None)
        except InputError as exc:
            print(str(exc) == direct, len(ahead))
        """,
        str(bad),
    )
    assert out.split() == ["True", "0"]


@needs_fork
def test_another_call_is_made_here_and_close_ends_the_child():
    out = fresh_python(
        """
        import os, time
        from mdvae_cli.run.read_ahead import ReadAhead

        ahead = ReadAhead()
        ahead.start(time.sleep, 30)
        (_, child, _), = ahead.children
        print(ahead.call(abs, -3), len(ahead))  # not the child's call: made here
        t = time.perf_counter()
        ahead.close()
        print(time.perf_counter() - t < 5, len(ahead))
        try:
            os.waitpid(child, 0)
        except ChildProcessError:
            print("reaped")
        """
    )
    assert out.split() == ["3", "1", "True", "0", "reaped"]


@needs_fork
def test_denoise_reads_a_bvh_ahead_and_writes_the_same_bytes(take, tmp_path):
    """The first input, a BVH, goes ahead (in a fresh process); on one core it does not, and
    the two outputs are byte for byte the same."""
    started = fresh_python(
        """
        import sys
        from mdvae_cli.cli.takes import read_ahead
        ahead = read_ahead([sys.argv[1], sys.argv[1], sys.argv[1]])
        print(type(ahead).__name__, len(ahead))  # a path named twice is read once
        ahead.close()
        print(read_ahead([sys.argv[1] + ".npz"]), read_ahead([sys.argv[1]], input_format="bvh"))
        """,
        str(take),
    )
    assert started.split() == ["ReadAhead", "1", "None", "None"]
    run = "import sys; from mdvae_cli.cli.main import main; sys.argv[0] = 'mdvae'; main()"
    outs = []
    for name, cores in (("two.bvh", None), ("one.bvh", {0})):
        fresh_python(run, "denoise", str(take), "-o", str(tmp_path / name), cores=cores)
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1]


COUNTED = """
import sys
from mdvae_cli.run import read_ahead

taken, made_here = [], []
call = read_ahead.ReadAhead.call
def counted(self, fn, *args, **kwargs):
    match = [c for c in self.children if read_ahead._same(c[0], (fn, args, kwargs))]
    (taken if match else made_here).append(args[0].name)
    return call(self, fn, *args, **kwargs)
read_ahead.ReadAhead.call = counted
from mdvae_cli.cli.main import cli
try:
    cli(sys.argv[1:])
except SystemExit as exc:
    assert exc.code in (0, None), exc.code
print(" ".join(taken), "|", " ".join(made_here))
"""


@needs_fork
def test_the_take_readers_of_denoise_and_view_take_the_childs_value(take, tmp_path):
    """Each BVH named is parsed once, in its child: the reader's call is the one the child
    made (a change to either would quietly read every take twice)."""
    clean, page = tmp_path / "clean.bvh", tmp_path / "page.html"
    out = fresh_python(COUNTED, "denoise", str(take), "-o", str(clean))
    assert out.split() == ["walk.bvh", "|"]
    out = fresh_python(COUNTED, "view", str(take), str(clean), "-o", str(page))
    assert out.split() == ["walk.bvh", "clean.bvh", "|"]
    assert page.stat().st_size > 0


def test_calls_with_arrays_are_not_matched():
    """Arguments that cannot say whether they are equal (arrays) make no match, no error."""
    call = (np.add, (np.zeros(3),), {})
    assert not read_ahead._same(call, (np.add, (np.zeros(3),), {}))
    assert read_ahead._same(
        (abs, (Path("a.bvh"),), {"fps": None}), (abs, (Path("a.bvh"),), {"fps": None})
    )


@needs_fork
def test_a_bad_bvh_read_ahead_still_gets_its_one_line_error(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mdvae_cli.cli.main", "denoise", str(bad), "-o",
         str(tmp_path / "o.bvh")], capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    assert done.returncode != 0
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "bad.bvh" in errors[0]
    assert not (tmp_path / "o.bvh").exists()
