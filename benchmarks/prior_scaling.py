"""What more motion would buy: priors trained on part of the training minutes, measured on
motion none of them saw.

    python benchmarks/prior_scaling.py RUN [RUN ...] [--corpus data/corpus]
                                       [--splits unseen_test,test] [--out docs/model.md]

For every prior run folder (``weights_recipe/scaling_curve.sh`` makes them): the training
minutes it saw (its config's ``data_fraction`` of the corpus's train split, whole files, and
the augmented windows), its steps, and its reconstruction of 60-frame windows of each split:
encoder -> decoder (the amortised pass; what regression mode builds on) and the encoder's
latents refined for ``--refine-steps`` steps on each window's training loss (the generative
model's own reach; ``benchmarks/prior.py``). V2V root-relative, cm, on the full mesh.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

try:
    from benchmarks import common
    from benchmarks.prior import reconstruction
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]
    from prior import reconstruction  # type: ignore[no-redef]

from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.train.corpus import fraction_of, read_split
from mdvae_cli.train.train_config import TrainConfig

SECTION_BEGIN = "<!-- prior_scaling:begin (written by benchmarks/prior_scaling.py) -->"
SECTION_END = "<!-- prior_scaling:end -->"


def training_minutes(corpus: Path, cfg: TrainConfig) -> tuple[float, int]:
    """Minutes of the train split a run's ``data_fraction`` kept, and how many files."""
    files = read_split(corpus / "split.json")["train"]
    motions = [load_motion(f) for f in files]
    keep = fraction_of(motions, cfg.data_fraction, cfg.seed)
    seconds = sum(motions[i].duration for i in keep)
    return seconds / 60.0, len(keep)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="prior run folders (or checkpoints)")
    ap.add_argument("--corpus", type=Path, default=Path("data/corpus"))
    ap.add_argument("--splits", default="unseen_test,test")
    ap.add_argument("--max-files", type=int, default=400)
    ap.add_argument("--refine-steps", type=int, default=50)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, help="markdown file to write the section into")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    splits = [s for s in args.splits.split(",") if s]
    rows, raw = [], []
    for run in args.runs:
        entry: dict = {"run": str(run)}
        for split in splits:
            prior, meta, body, files, windows = common.prior_and_windows(
                run, args.corpus, split, args.max_files
            )
            cfg = TrainConfig.from_dict(meta["train_config"])
            amortised = reconstruction(prior, body, windows)
            refined = reconstruction(prior, body, windows, train=cfg, steps=args.refine_steps)
            entry[split] = {"windows": len(windows), "amortised": amortised, "refined": refined}
        minutes, n_files = training_minutes(args.corpus, cfg)
        entry.update(minutes=round(minutes, 1), files=n_files, steps=meta.get("step"),
                     speeds=cfg.speeds, mirror=cfg.mirror_augment)  # fmt: skip
        raw.append(entry)
        aug = (
            "+".join(
                [
                    *(["time-warp"] if len(cfg.speeds) > 1 else []),
                    *(["mirror"] if cfg.mirror_augment else []),
                ]
            )
            or "none"
        )
        rows.append(
            [run.name, f"{minutes:.1f}", str(n_files), aug, str(meta.get("step", "-")),
             *(f"{entry[s]['amortised']['v2v_cm']:.2f} / {entry[s]['refined']['v2v_cm']:.2f}"
               for s in splits)]
        )  # fmt: skip
        print(f"[{time.perf_counter() - start:6.0f}s] {run}: {rows[-1]}", file=sys.stderr)
    cols = [f"{s}: encoder / + {args.refine_steps} steps (V2V cm)" for s in splits]
    header = ["run", "training minutes", "files", "augmentation", "steps", *cols]
    table = common.markdown_table(header, rows)
    text = "\n".join([
        SECTION_BEGIN,
        "",
        table,
        "",
        f"`python benchmarks/prior_scaling.py {' '.join(sys.argv[1:] if argv is None else argv)}`"
        f" ({time.perf_counter() - start:.0f} s, {common.cpu_model()}).",
        "",
        SECTION_END,
    ]) + "\n"  # fmt: skip
    if args.out:
        common.write_section(args.out, text, SECTION_BEGIN, SECTION_END)
    if args.json:
        args.json.write_text(json.dumps(raw, indent=2) + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
