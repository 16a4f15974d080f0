"""Motion-DVAE paper Table 1 and Figure 1 on held-out CMU subjects.

    python benchmarks/denoise_table.py [--corpus data/corpus] [--out docs/benchmarks.md]
                                       [--max-clips N] [--quick]

Protocol. The test-split files (resampled to 30 Hz) are cut into non-overlapping 60-frame
(2 s) clips. Pose-NDF noise of sigma = 0.10, 0.15 and 0.20 rad is added to every clip, with a
seed fixed per clip and sigma. Every method then runs file to file on the noisy clips, and the
timed part is loading, denoising and saving all of them in one run:

* ground truth and observations (the noisy input), for reference;
* a Gaussian and a Savitzky-Golay filter (``mdvae_cli.filters``). Their parameters are tuned by
  grid search on clips of the val split at sigma = 0.15, for the lowest V2V;
* regression mode: one forward pass of the denoiser;
* optimisation mode: for each sigma, a copy of the denoiser is fine-tuned for 50 steps on all
  the test clips of that sigma at once, which then predicts them (the paper's protocol);
* the default (``mdvae denoise``): regression mode, the closed-form slow offset, the input's
  unexplained part blended back and the foot lock; and the same with ``--feet off``;
* refinement (``mdvae denoise --refine 50``): regression mode, then 50 gradient steps on each
  window's own latents, with a slow rotation offset (``mdvae_cli.infer.refine``).

Every row of ours runs through the library call the command makes
(``mdvae_cli.infer.denoise_settings.denoise``), so it measures what a user gets.

The metrics are root-relative V2V (cm) and the mean joint acceleration (m/s^2; the ground truth
row gives the target value), frame-weighted over all clips. Speed is s/frame and frames/s of the
file-to-file run at sigma = 0.15, plus, for the filters and regression mode, one clip processed
alone after a warm-up. Figure 1 plots V2V against s/frame at sigma = 0.15 for 0, 20, 50, 100
and 250 optimisation steps, with the filters as reference points (matplotlib, optional).

The table, the machine description and the plot link go into a marked section of ``--out``
(other content of that file is kept). ``--quick`` runs a small subset to check that everything
works. Its numbers mean little, and it writes ``--out`` only when that is given explicitly.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path

import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/denoise_table.py
    import common  # type: ignore[no-redef]
try:
    from benchmarks.denoise_rows import (
        CURVE_STEPS,
        REPO,
        TableSettings,
        section_markers,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_rows import (  # type: ignore[no-redef]
        CURVE_STEPS,
        REPO,
        TableSettings,
        section_markers,
    )
try:
    from benchmarks.denoise_methods import build_table
except ModuleNotFoundError:  # run as a file
    from denoise_methods import build_table  # type: ignore[no-redef]
try:
    from benchmarks.short_takes import SECTION_BEGIN as SHORT_BEGIN
    from benchmarks.short_takes import SECTION_END as SHORT_END
    from benchmarks.short_takes import load_short_clips, short_take_rows, short_takes_markdown
except ModuleNotFoundError:  # run as a file
    from short_takes import SECTION_BEGIN as SHORT_BEGIN  # type: ignore[no-redef]
    from short_takes import SECTION_END as SHORT_END  # type: ignore[no-redef]
    from short_takes import (  # type: ignore[no-redef]
        load_short_clips,
        short_take_rows,
        short_takes_markdown,
    )
try:
    from benchmarks.denoise_report import (
        plot_speed_accuracy,
        report_markdown,
        table_columns,
        table_rows,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_report import (  # type: ignore[no-redef]
        plot_speed_accuracy,
        report_markdown,
        table_columns,
        table_rows,
    )

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.infer.settings import RefineConfig

# --------------------------------------------------------------------------------------------
# command line


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "corpus")
    p.add_argument(
        "--splits",
        default="test,unseen_test",
        help="corpus splits to tabulate: test (filters tuned on val clips) and unseen_test "
        "(filters tuned on the very clips, as the issue's table did)",
    )
    p.add_argument(
        "--short-lengths",
        default="6,10,16,30,60",
        help="clip lengths of the short-take table (benchmarks/short_takes.py); empty = none",
    )
    p.add_argument("--short-split", default="unseen_test", help="split of the short takes")
    p.add_argument(
        "--rows",
        help="comma-separated method rows to run (names as in the table, e.g. 'Regression "
        "mode,Regression + offset (default)'); default all",
    )
    p.add_argument("--short-clips", type=int, default=64, help="short clips per length")
    p.add_argument("--split", type=Path, help="split file (default: CORPUS/split.json)")
    p.add_argument(
        "--out",
        type=Path,
        help="markdown file to write the section into (default: docs/benchmarks.md; "
        "with --quick only when given)",
    )
    p.add_argument("--plot", type=Path, help="PNG (default: denoise_speed_accuracy.png by --out)")
    p.add_argument("--json", type=Path, help="also write the raw numbers here")
    p.add_argument("--denoiser", type=Path, help="denoiser checkpoint (default: shipped)")
    p.add_argument("--body-model", type=Path, help="SMPL-family file (default: built-in body)")
    p.add_argument("--max-files", type=int, help="use at most this many files per split")
    p.add_argument("--max-clips", type=int, help="test clips to use, spread evenly (default all)")
    p.add_argument("--tune-clips", type=int, default=100, help="val clips for the filter grid")
    p.add_argument("--clip-frames", type=int, default=60, help="frames per clip (2 s at 30 Hz)")
    p.add_argument("--optimize-steps", type=int, default=50)
    p.add_argument("--curve-steps", default=",".join(map(str, CURVE_STEPS)))
    p.add_argument(
        "--refine-steps", type=int, default=RefineConfig.steps, help="steps of the refinement row"
    )
    p.add_argument(
        "--refine-offset",
        type=float,
        default=RefineConfig.offset_std,
        help="slow-offset scale of the refinement row",
    )
    p.add_argument("--threads", type=int, default=2, help="torch threads (the product's target)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workdir", type=Path, help="scratch folder (default: a temporary one)")
    p.add_argument("--quick", action="store_true", help="a small subset, to check the script")
    return p.parse_args(argv)


def settings_from_args(args: argparse.Namespace, window: int) -> TableSettings:
    s = TableSettings(
        optimize_steps=args.optimize_steps,
        curve_steps=tuple(int(x) for x in str(args.curve_steps).split(",") if x.strip()),
        window=window,
        stride=max(1, window * 3 // 4),
        seed=args.seed,
        refine_steps=args.refine_steps,
        refine_offset=args.refine_offset,
        rows=tuple(r.strip() for r in args.rows.split(",")) if args.rows else None,
    )
    if args.quick:
        s.refine_steps = min(s.refine_steps, 10)
        s.gaussian_grid = (1.0, 2.0, 3.0)
        s.savgol_grid = ((7, 2), (11, 2), (15, 3))
        s.curve_steps = tuple(n for n in s.curve_steps if n <= s.optimize_steps)
        s.single_clip_repeats = 2
    return s


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with an ``error:`` line when the inputs are missing."""
    command = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(command)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        return _run(args, command)
    finally:
        torch.set_num_threads(previous_threads)  # leave a calling process as it was


def _run(args: argparse.Namespace, command: list[str]) -> int:
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.errors import MdvaeError
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.train.corpus import read_split

    if args.quick:
        args.max_files = args.max_files or 6
        args.max_clips = args.max_clips or 24
        args.tune_clips = min(args.tune_clips, 12)
        args.short_clips = min(args.short_clips, 4)
    start = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - start:7.1f}s] {message}", file=sys.stderr, flush=True)

    try:
        split_file = args.split or args.corpus / "split.json"
        if not split_file.is_file():
            raise MdvaeError(f"no split file at {split_file} (is the corpus built?)")
        split = read_split(split_file)
        splits = [x for x in args.splits.split(",") if x.strip()]
        tune_split = {"test": "val"}  # other splits tune the filters on their very clips
        needed = {*splits, *(tune_split[x] for x in splits if x in tune_split)}
        missing = [k for k in sorted(needed) if not split.get(k)]
        if missing:
            raise MdvaeError(f"{split_file}: no files in split(s) {', '.join(missing)}")
        denoiser, meta = load_denoiser(args.denoiser)
        window = int(meta.get("fit_config", {}).get("window", 60))
        body = BodyModel(load_body_model(args.body_model))
        root = split_file.parent
        settings = settings_from_args(args, window)
        results, used = [], {}
        for name in splits:
            test_files = common.pick_evenly(split[name], args.max_files)
            log(f"loading {len(test_files)} {name} files")
            test = common.load_clips(test_files, root, args.clip_frames, max_clips=args.max_clips)
            if name in tune_split:
                val_files = common.pick_evenly(split[tune_split[name]], args.max_files)
                val = common.load_clips(val_files, root, args.clip_frames,
                                        max_clips=args.tune_clips)  # fmt: skip
                tuned_on = tune_split[name]
            else:
                val_files, val, tuned_on = test_files, test, "the same"
            if not test or not val:
                raise MdvaeError(f"no clip of {args.clip_frames} frames in the {name} files")
            used[name] = (len(test_files), len(val_files), tuned_on)
            own = settings if name == "test" else replace(
                settings, curve_steps=tuple(n for n in settings.curve_steps
                                            if n in (0, settings.optimize_steps)))  # fmt: skip
            with tempfile.TemporaryDirectory(prefix="mdvae-bench-") as tmp:
                work = args.workdir or Path(tmp)
                work.mkdir(parents=True, exist_ok=True)
                results.append(build_table(test, val, denoiser, body, own, work, log, name,
                                           tuned_on))  # fmt: skip
        short_rows = []
        lengths = [int(x) for x in args.short_lengths.split(",") if x.strip()]
        if lengths:
            files = split.get(args.short_split) or []
            short = load_short_clips(files, root, lengths, args.short_clips)
            short_rows = short_take_rows(short, denoiser, body, seed=args.seed, log=log)
    except MdvaeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    out = args.out if (args.out or args.quick) else REPO / "docs" / "benchmarks.md"
    machine = common.machine_description()
    payload = {"machine": machine, "tables": [], "short_takes": []}
    for result in results:
        n_test, n_val, tuned_on = used[result.split]
        context = {
            "corpus": f"{args.corpus} (split {split_file.name}: {n_test} {result.split} files"
            + (f", {n_val} {tuned_on} files" if tuned_on != "the same" else "")
            + " used)",
            "denoiser": str(args.denoiser or "shipped weights (mdvae_cli/weights/denoiser.npz)"),
            "body model": str(args.body_model or "built-in body"),
            "denoiser windows": f"{settings.window} frames, stride {settings.stride}",
            "run": "quick subset (--quick): numbers are only a smoke test"
            if args.quick
            else ("all clips" if args.max_clips is None and args.max_files is None else "subset"),
            "command": " ".join(["python benchmarks/denoise_table.py", *command]),
            "benchmark time (all tables)": f"{time.perf_counter() - start:.0f} s",
        }
        plot_link = None
        if out is not None:
            if result.split == "test":
                plot = args.plot or out.parent / "denoise_speed_accuracy.png"
                if plot_speed_accuracy(result, plot):
                    plot_link = os.path.relpath(plot, out.parent)
                else:
                    log("matplotlib is not installed: no plot (pip install matplotlib)")
            begin, end = section_markers(result.split)
            common.write_section(
                out, report_markdown(result, machine, context, plot_link), begin, end
            )
            log(f"wrote the {result.split} table to {out}")
        payload["tables"].append({**result.to_dict(), "context": context})
        print(f"\n{result.split} ({result.num_clips} clips):")
        print(common.markdown_table(table_columns(result.settings), table_rows(result)))
    if short_rows:
        context = {
            "split": f"{args.short_split} of {args.corpus}",
            "denoiser": str(args.denoiser or "shipped weights"),
            "command": " ".join(["python benchmarks/denoise_table.py", *command]),
        }
        text = short_takes_markdown(short_rows, context)
        if out is not None:
            common.write_section(out, text, SHORT_BEGIN, SHORT_END)
        payload["short_takes"] = [asdict(r) for r in short_rows]
        print("\n" + text)
    if args.json:
        args.json.write_text(json.dumps(payload, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
