"""weights_recipe/pack_corpus.py: the compact copy of a corpus that a short GPU run carries."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.train.corpus import load_windows, select_files
from tests.conftest import motion_arrays

REPO = Path(__file__).resolve().parents[1]


def pack_module():
    spec = importlib.util.spec_from_file_location("pack", REPO / "weights_recipe/pack_corpus.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_split_corpus(folder: Path) -> Path:
    lists = {"train": ["a/t0.npz", "a/t1.npz"], "val": ["b/v0.npz"], "test": ["c/x0.npz"]}
    for i, rel in enumerate(f for files in lists.values() for f in files):
        arrays = motion_arrays(T=70, width=156, fps=30.0, seed=i)
        arrays["poses"][:, 0] = np.pi / 2
        arrays["poses"][:, 66:] = 0.3  # hands: training never reads them
        arrays["source"] = np.asarray("somewhere/" + rel)
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        np.savez(folder / rel, **arrays)
    (folder / "split.json").write_text(json.dumps({"format": "x", "fps": 30.0, "splits": lists}))
    return folder


def test_packed_copy_gives_the_same_windows_and_only_the_chosen_lists(tmp_path, tiny_body):
    corpus = write_split_corpus(tmp_path / "corpus")
    out = tmp_path / "pack"
    assert pack_module().main([str(corpus), str(out), "--splits", "train,val"]) == 0
    split = json.loads((out / "split.json").read_text())
    assert sorted(split["splits"]) == ["train", "val"] and split["fps"] == 30.0
    assert not (out / "c").exists()  # test motion is not carried
    with np.load(out / "a/t0.npz") as d:
        assert d["poses"].shape == (70, 66)
        assert "source" not in d.files
    body = BodyModel(tiny_body)
    for name in ("train", "val"):
        a = select_files([corpus], corpus / "split.json", name)
        b = select_files([out], out / "split.json", name)
        wa = load_windows(a, body, 20, 5, mirror=True, speeds=(0.8, 1.0))
        wb = load_windows(b, body, 20, 5, mirror=True, speeds=(0.8, 1.0))
        assert len(wa) == len(wb) > 0
        assert torch.equal(wa.x, wb.x) and torch.equal(wa.x0, wb.x0)


def test_pack_refuses_an_existing_folder_and_an_unknown_list(tmp_path):
    corpus = write_split_corpus(tmp_path / "corpus")
    with pytest.raises(SystemExit, match="exists"):
        pack_module().main([str(corpus), str(corpus)])
    with pytest.raises(SystemExit, match="no list unseen_val"):
        pack_module().main([str(corpus), str(tmp_path / "p"), "--splits", "train,unseen_val"])
