"""A compact copy of the corpus for a training run on another machine (the GPU recipe,
``gpu_prior.sh``): only the splits a prior run reads (train and the validation lists), and of
each file only what training reads (the 22 body joints' rotations, translation, shape, rate,
gender), as stored, compressed. The windows built from the copy are the corpus's own, bit for bit.

    python weights_recipe/pack_corpus.py data/corpus data/corpus_pack [--splits LIST,...]

The copy keeps the corpus's folder layout and writes its own ``split.json`` (the same format,
the chosen lists only), so ``mdvae train-prior data/corpus_pack --split
data/corpus_pack/split.json`` trains exactly as on the full corpus. Prints its size.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: what training reads of an AMASS-layout file: the root and 21 body joints' axis-angles
BODY_COLUMNS = 66


def pack_file(src: Path, dst: Path) -> int:
    """Copy one corpus file's training content to ``dst``.  -> bytes written"""
    with np.load(src, allow_pickle=False) as d:
        keep = {
            "poses": d["poses"][:, :BODY_COLUMNS],
            "trans": d["trans"],
            "betas": d["betas"],
            "mocap_framerate": np.asarray(d["mocap_framerate"]),
            "gender": np.asarray(d["gender"]),
        }
    dst.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(dst, **keep)
    return dst.stat().st_size


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("corpus", type=Path, help="a corpus folder (build_corpus.sh)")
    ap.add_argument("out", type=Path, help="the folder to write (must not exist)")
    ap.add_argument("--splits", default="train,val,unseen_val", help="split lists to copy")
    args = ap.parse_args(argv)
    if args.out.exists():
        raise SystemExit(f"{args.out} exists: give a new folder")
    split = json.loads((args.corpus / "split.json").read_text())
    names = [s for s in args.splits.split(",") if s]
    missing = [s for s in names if s not in split["splits"]]
    if missing:
        raise SystemExit(f"{args.corpus}/split.json has no list {', '.join(missing)}")
    total = 0
    for name in names:
        for rel in split["splits"][name]:
            total += pack_file(args.corpus / rel, args.out / rel)
    kept = {**split, "splits": {s: split["splits"][s] for s in names}}
    (args.out / "split.json").write_text(json.dumps(kept, indent=1) + "\n")
    files = sum(len(split["splits"][s]) for s in names)
    print(f"wrote {files} files ({', '.join(names)}) to {args.out}: {total / 2**20:.1f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
