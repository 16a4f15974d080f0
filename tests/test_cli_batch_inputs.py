"""What a shell pipeline gets when its inputs or output name are wrong: one missing input of
several fails alone, an empty -o is refused, and --json always prints a JSON document."""

from __future__ import annotations

import json

import pytest

from mdvae_cli.formats.npz_io import load_motion
from tests.conftest import run_cli as run


def test_one_missing_input_of_several_fails_alone(make_motion_file, tmp_path):
    a = make_motion_file("a.npz", T=12)
    b = make_motion_file("b.npz", T=14, seed=1)
    gone = tmp_path / "gone.npz"
    code, out, err = run("add-noise", a, gone, b, "-o", tmp_path / "out", "--sigma", 0.1,
                         "--json")  # fmt: skip
    assert code == 1
    doc = json.loads(out)
    assert (doc["succeeded"], doc["failed"]) == (2, 1)
    (bad,) = [f for f in doc["files"] if not f["ok"]]
    assert bad["input"] == str(gone) and bad["error"].endswith(f"no such file or folder: {gone}")
    assert load_motion(tmp_path / "out" / "a.npz").num_frames == 12
    assert load_motion(tmp_path / "out" / "b.npz").num_frames == 14
    assert not (tmp_path / "out" / "gone.npz").exists()
    # every input missing: refused before anything, as one missing file always was
    code, out, err = run("add-noise", gone, tmp_path / "gone2.npz", "-o", tmp_path / "o2")
    assert code == 1 and "no such file or folder" in err and not (tmp_path / "o2").exists()


@pytest.mark.parametrize("command", ["denoise", "add-noise", "import", "export-bvh", "view"])
def test_an_empty_output_name_is_refused(make_motion_file, tmp_path, monkeypatch, command):
    src = make_motion_file("a.npz", T=12)
    monkeypatch.chdir(tmp_path)
    code, out, err = run(command, src, "-o", "")
    assert code == 1 and "'-o' / '--out': is empty: name an output file or folder" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


@pytest.mark.parametrize(
    "args, words",
    [
        (["denoise", "{missing}", "-o", "{out}"], "no such file or folder"),
        (["denoise", "{src}", "-o", "{src}"], "refusing to overwrite"),
        (["denoise", "{src}", "-o", "{out}", "--fps", "abc"], "Invalid value"),
        (["eval", "--gt", "{missing}", "--pred", "{src}"], "no such file or folder"),
    ],
)
def test_json_runs_print_a_json_document_even_when_refused(make_motion_file, tmp_path, args,
                                                         words):  # fmt: skip
    src = make_motion_file("a.npz", T=12)
    names = {"src": src, "missing": tmp_path / "missing.npz", "out": tmp_path / "o.npz"}
    code, out, err = run(*(a.format(**names) for a in args), "--json")
    assert code == 1
    doc = json.loads(out)
    assert doc["ok"] is False and doc["exit_code"] == 1 and words in doc["error"]
    assert err.strip().splitlines()[-1] == f"error: {doc['error']}"
