"""Symlinks among the inputs: a folder's every file path is its own job (a symlink too, and the
file it points to), a path named twice counts once, a broken link is skipped with a note, and a
training corpus counts a file reached by two paths once."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from mdvae_cli.errors import InputError
from mdvae_cli.fileio import entry_of, expand_inputs

pytestmark = pytest.mark.skipif(os.name == "nt", reason="symlinks")


@pytest.fixture
def linked(tmp_path, make_motion_file) -> Path:
    """in/b/take.npz, in/a/link_take.npz -> ../b/take.npz (the batch2 folder of the sweep)."""
    make_motion_file("in/b/take.npz", T=30)
    (tmp_path / "in/a").mkdir()
    (tmp_path / "in/a/link_take.npz").symlink_to("../b/take.npz")
    return tmp_path / "in"


def rels(items) -> list[str]:
    return [rel.as_posix() for _, rel in items]


def test_a_link_and_the_file_it_points_to_are_two_items(linked):
    assert rels(expand_inputs([linked])) == ["a/link_take.npz", "b/take.npz"]
    # a training corpus: one take, however many paths lead to it
    assert len(expand_inputs([linked], by_target=True)) == 1


def test_a_path_named_twice_counts_once(linked, monkeypatch):
    take = linked / "b/take.npz"
    monkeypatch.chdir(linked)
    items = expand_inputs([take, Path("b/take.npz"), Path("a/../b/take.npz")])
    assert rels(items) == ["take.npz"]
    # named and also inside a folder named: the folder's item
    assert rels(expand_inputs([linked, take])) == ["a/link_take.npz", "b/take.npz"]
    # the link named with the file it points to: two paths, two items
    assert len(expand_inputs([linked / "a/link_take.npz", take])) == 2
    assert entry_of(Path("a/link_take.npz")) == linked / "a/link_take.npz"


def test_broken_and_looping_links_in_a_folder_are_skipped_with_a_note(linked):
    (linked / "a/gone.npz").symlink_to("/nonexistent/x.npz")
    (linked / "a/loop.npz").symlink_to("loop.npz")
    (linked / "a/readme.txt").symlink_to("/nonexistent/readme.txt")  # not a motion name
    notes: list[str] = []
    items = expand_inputs([linked], notes=notes)
    assert rels(items) == ["a/link_take.npz", "b/take.npz"]
    assert notes == [
        "a/gone.npz: a broken link (to /nonexistent/x.npz); skipped",
        "a/loop.npz: a link that loops; skipped",
    ]
    assert expand_inputs([linked]) == items  # no list given: skipped all the same
    with pytest.raises(InputError, match="no such file or folder"):
        expand_inputs([linked / "a/gone.npz"])  # named: missing, as any missing path


def test_denoise_writes_the_link_and_the_file_it_points_to(linked, tmp_path):
    (linked / "a/gone.npz").symlink_to("/nonexistent/x.npz")
    out = tmp_path / "out"
    code, _, err = run_cli("denoise", linked, "-o", out)
    assert code == 0, err
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.npz")) == [
        "a/link_take.npz",
        "b/take.npz",
    ]
    assert not (out / "a/link_take.npz").is_symlink()
    assert "denoised 2 file(s)" in " ".join(err.split())
    assert "note: a/gone.npz: a broken link (to /nonexistent/x.npz); skipped" in err
    # the same take twice: its windows share one batch, where a product may round a row
    # differently by its place in it (3e-9 rad seen, in the slow offset's cosine fit)
    with np.load(out / "a/link_take.npz") as a, np.load(out / "b/take.npz") as b:
        np.testing.assert_allclose(a["poses"], b["poses"], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(a["trans"], b["trans"])


def test_a_file_named_twice_writes_one_output(linked, tmp_path):
    take = linked / "b/take.npz"
    code, _, err = run_cli("add-noise", take, linked / "a/../b/take.npz", "-o", tmp_path / "o")
    assert code == 0, err
    assert [p.name for p in (tmp_path / "o").iterdir()] == ["take.npz"]
    code, _, err = run_cli("denoise", take, take, "-o", tmp_path / "one.npz")
    assert code == 0 and (tmp_path / "one.npz").is_file(), err


def test_eval_and_view_note_broken_links(linked, tmp_path):
    (linked / "a/gone.npz").symlink_to("/nonexistent/x.npz")
    code, _, err = run_cli("eval", "--gt", linked, "--pred", linked)
    assert code == 0, err
    assert "note: in/a/gone.npz: a broken link" in err
    code, _, err = run_cli("view", linked, "-o", tmp_path / "v.html")
    assert "note: a/gone.npz: a broken link" in err, err


def test_training_notes_broken_links(linked, capsys):
    from mdvae_cli.cli.batch import note_broken_links

    (linked / "a/gone.npz").symlink_to("/nonexistent/x.npz")
    note_broken_links([str(linked / "absent"), str(linked)])  # a missing path: the trainer's
    err = capsys.readouterr().err
    assert "note: a/gone.npz: a broken link (to /nonexistent/x.npz); skipped" in err
