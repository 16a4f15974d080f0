"""Long takes: the whole `mdvae denoise` / `mdvae view` process on 1-, 10- and 30-minute takes.

    python benchmarks/long_takes.py [--minutes 1 10 30] [--formats npz bvh]
                                    [--runs default refine view] [--baseline DIR] [--write]

Protocol. A take of N minutes is made once into ``--work``: the files of a corpus split
(``--corpus``, resampled) end to end, each one's root moved on to where the last one ended,
with Pose-NDF noise (sigma 0.10 rad, seed 0); as AMASS npz at 30 Hz and as BVH at 120 Hz (the
SMPL skeleton, ``registry.write``). Each run is a fresh process (``python -m
mdvae_cli.cli.main``, one torch thread): its wall time from start to exit and its peak resident
memory (its own since its start, ``VmHWM`` read as it exits: :data:`OWN_PEAK`). Runs:
``default`` (`mdvae denoise take -o clean`), ``refine`` (`--refine 50`), ``view`` (`mdvae view
take clean -o page.html`, on the default's output), and ``scipy``: the same file read and
written by the same reader and writer (npz: ``npz_io.load_motion`` / ``save_motion``; BVH:
``formats.bvh.load_bvh`` / ``write_bvh``) with ``scipy.signal.savgol_filter`` (9 frames, order
2) over its channels in between; the others are quoted as ratios to it. With ``--baseline DIR``
(a tree holding another ``mdvae_cli``) every run is done there too, alternating with this
tree's, and the table quotes both and how far the outputs are apart (npz: max |difference| of
poses (rad) and trans (m); BVH: of the channel values). With ``--repeats N`` each run is done N
times (this tree's and the baseline's in turn) and the table quotes the median wall time and
the largest peak: on a shared machine one run's time can move by a fifth. Each tree's modules
are compiled first (``compileall``), as an installed package has them: a Python told not to
write bytecode (``PYTHONDONTWRITEBYTECODE``) would compile every module in every run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
RATES = {"npz": 30.0, "bvh": 120.0}
SECTION_BEGIN = "<!-- long_takes:begin (written by benchmarks/long_takes.py) -->"
SECTION_END = "<!-- long_takes:end -->"
README_BEGIN = "<!-- long_takes_readme:begin (written by benchmarks/long_takes.py) -->"
README_END = "<!-- long_takes_readme:end -->"

SCIPY_PASS = """
import sys
import numpy as np
from scipy.signal import savgol_filter
src, out = sys.argv[1], sys.argv[2]
if src.endswith(".npz"):
    from mdvae_cli.formats.npz_io import load_motion, save_motion
    m = load_motion(src)
    T = m.num_frames
    f = lambda x: savgol_filter(x.reshape(T, -1), 9, 2, axis=0).reshape(x.shape)
    save_motion(m.with_body(f(m.root_orient), f(m.pose_body), f(m.trans)), out)
else:
    from mdvae_cli.formats.bvh import load_bvh
    from mdvae_cli.formats.bvh_write import write_bvh
    layout = load_bvh(src).layout
    data = layout.data.copy()
    data[layout.rows] = savgol_filter(data[layout.rows], 9, 2, axis=0)
    write_bvh(layout, data, out)
"""

#: runs a child's command (``-m module ...`` or ``-c code ...``, its own arguments after it)
#: and, as it exits, writes its peak resident memory in kB (``VmHWM``: the peak of its own
#: memory since its start) to the file ``MDVAE_BENCH_PEAK`` names. wait4's ``ru_maxrss`` is
#: not that: Linux counts the parent's resident memory at the fork in it, so every run after
#: this script had made a 30-minute take quoted the script's 1.7 GB.
OWN_PEAK = """
import atexit, os, runpy, sys
def _peak():
    try:
        with open("/proc/self/status") as f:
            kb = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
        with open(os.environ["MDVAE_BENCH_PEAK"], "w") as f:
            f.write(str(kb))
    except (OSError, StopIteration, KeyError):
        pass
atexit.register(_peak)
flag, what, *rest = sys.argv[1:]
sys.argv = [what if flag == "-m" else "-c", *rest]
if flag == "-m":
    runpy.run_module(what, run_name="__main__", alter_sys=True)
else:
    exec(compile(what, "<string>", "exec"), {"__name__": "__main__"})
"""


# --------------------------------------------------------------------------------------------
# takes


def make_take(corpus: Path, minutes: float, fps: float, path: Path, sigma: float = 0.10) -> Path:
    """A noisy take of ``minutes`` at ``fps`` (module docstring) written to ``path`` (kept:
    made once)."""
    if path.exists():
        return path
    from mdvae_cli.formats.registry import write
    from mdvae_cli.motion.noise import add_pose_noise

    files = sorted(corpus.rglob("*.npz"))
    if not files:
        raise SystemExit(f"no .npz files under {corpus}: pass --corpus")
    take = common.join_files(files, minutes, fps)
    noisy = add_pose_noise(take, sigma, np.random.default_rng(0))
    path.parent.mkdir(parents=True, exist_ok=True)
    write(noisy, path)
    return path


# --------------------------------------------------------------------------------------------
# runs


@dataclass
class Run:
    """One process: wall seconds, peak resident memory (MB), what it printed."""

    seconds: float
    peak_mb: float
    output: str


def run_process(args: list[str], tree: Path, threads: int) -> Run:
    """Run ``python args`` in ``tree`` (first on the path: ``python -m`` puts the working
    folder before PYTHONPATH); its wall time and peak memory."""
    with tempfile.TemporaryDirectory() as scratch:
        peak_file = Path(scratch) / "peak_kb"
        env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": str(threads),
               "MKL_NUM_THREADS": str(threads), "MDVAE_BENCH_PEAK": str(peak_file)}  # fmt: skip
        start = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-c", OWN_PEAK, *args], env=env, cwd=tree, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        out = proc.stdout.read().decode(errors="replace")
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}):\n{out[-2000:]}")
        # without /proc: wait4's figure, which counts this process's memory too
        peak_kb = int(peak_file.read_text()) if peak_file.exists() else usage.ru_maxrss
    return Run(seconds, peak_kb / 1024, out)


def compile_tree(tree: Path) -> None:
    """Byte-compile ``tree``'s ``mdvae_cli`` (module docstring)."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "mdvae_cli")],
                   check=True, stdout=subprocess.DEVNULL)  # fmt: skip


def typical(runs: list[Run]) -> Run:
    """Repeats of one run: the median wall time, the largest peak, the last output."""
    return Run(float(np.median([r.seconds for r in runs])), max(r.peak_mb for r in runs),
               runs[-1].output)  # fmt: skip


def commands(kind: str, take: Path, out: Path) -> list[str]:
    """The process arguments of one run on ``take`` writing ``out``."""
    cli = ["-m", "mdvae_cli.cli.main"]
    if kind == "scipy":
        return ["-c", SCIPY_PASS, str(take), str(out)]
    if kind == "default":
        return [*cli, "denoise", str(take), "-o", str(out)]
    if kind == "refine":
        return [*cli, "denoise", str(take), "-o", str(out), "--refine", "50"]
    if kind == "view":  # the default's output next to the take
        clean = out.with_name(out.name.replace("view", "default")).with_suffix(take.suffix)
        return [*cli, "view", str(take), str(clean), "-o", str(out)]
    raise ValueError(kind)


def output_gap(a: Path, b: Path) -> float:
    """How far two outputs of the same run are apart (module docstring)."""
    if a.suffix == ".npz":
        from mdvae_cli.formats.npz_io import load_motion

        ma, mb = load_motion(a), load_motion(b)
        return float(max(np.abs(ma.poses[:, :66] - mb.poses[:, :66]).max(),
                         np.abs(ma.trans - mb.trans).max()))  # fmt: skip
    if a.suffix == ".bvh":
        from mdvae_cli.formats.bvh import load_bvh

        return float(np.abs(load_bvh(a).layout.data - load_bvh(b).layout.data).max())
    return float("nan")


@dataclass
class Row:
    """One run on one take, with the baseline's where there is one."""

    fmt: str
    minutes: float
    frames: int
    kind: str
    now: Run
    page_mb: float | None = None
    before: Run | None = None
    gap: float | None = None


def measure(args) -> list[Row]:
    """Every run on every take (the baseline's alternating with this tree's)."""
    work = Path(args.work)
    rows: list[Row] = []
    for tree in [REPO] + ([Path(args.baseline)] if args.baseline else []):
        compile_tree(tree)
    for fmt in args.formats:
        for minutes in args.minutes:
            fps = RATES[fmt]
            take = make_take(Path(args.corpus), minutes, fps, work / f"take_{minutes:g}min.{fmt}")
            frames = int(round(minutes * 60 * fps))
            for kind in ["scipy", *args.runs]:
                suffix = ".html" if kind == "view" else f".{fmt}"
                trees = [("now", REPO)] + ([("before", Path(args.baseline))] if args.baseline
                                           else [])  # fmt: skip
                done: dict[str, list[Run]] = {name: [] for name, _ in trees}
                outs = {}
                for _ in range(args.repeats):
                    for name, tree in trees:
                        outs[name] = work / name / f"{kind}_{minutes:g}min{suffix}"
                        outs[name].parent.mkdir(parents=True, exist_ok=True)
                        run = run_process(commands(kind, take, outs[name]), tree, args.threads)
                        done[name].append(run)
                        print(f"{fmt} {minutes:g} min {kind} [{name}]: {run.seconds:.1f} s, "
                              f"{run.peak_mb:.0f} MB", file=sys.stderr, flush=True)  # fmt: skip
                runs = {name: typical(rs) for name, rs in done.items()}
                row = Row(fmt, minutes, frames, kind, runs["now"], before=runs.get("before"))
                if kind == "view":
                    row.page_mb = outs["now"].stat().st_size / 1e6
                if "before" in outs and kind != "scipy":
                    row.gap = output_gap(outs["now"], outs["before"])
                rows.append(row)
    return rows


# --------------------------------------------------------------------------------------------
# the table


def table(rows: list[Row]) -> str:
    """Markdown: per take and run, wall time, frames/s, peak memory, ratios."""
    scipy = {(r.fmt, r.minutes): r.now.seconds for r in rows if r.kind == "scipy"}
    default = {(r.fmt, r.minutes): r.now.seconds for r in rows if r.kind == "default"}
    baseline = any(r.before is not None for r in rows)
    header = ["take", "frames", "run", "wall (s)", "frames/s", "peak (MB)", "x scipy pass"]
    if baseline:
        header += ["before: wall (s)", "before: peak (MB)", "speed-up", "output vs before"]
    body = []
    for r in rows:
        note = ""
        if r.kind == "view" and (r.fmt, r.minutes) in default:
            times = r.now.seconds / default[(r.fmt, r.minutes)]
            note = f" (page {r.page_mb:.1f} MB, x{times:.2f} the default)"
        cells = [
            f"{r.minutes:g} min {r.fmt} ({RATES[r.fmt]:g} Hz)",
            f"{r.frames:,}",
            r.kind + note,
            f"{r.now.seconds:.1f}",
            f"{r.frames / r.now.seconds:,.0f}",
            f"{r.now.peak_mb:,.0f}",
            f"{r.now.seconds / scipy[(r.fmt, r.minutes)]:.2f}",
        ]
        if baseline and r.before is not None:
            gap = "" if r.gap is None or np.isnan(r.gap) else f"{r.gap:.2g}"
            cells += [f"{r.before.seconds:.1f}", f"{r.before.peak_mb:,.0f}",
                      f"{r.before.seconds / r.now.seconds:.2f}", gap]  # fmt: skip
        body.append(cells)
    return common.markdown_table(header, body)


def section(rows: list[Row], argv: list[str]) -> str:
    machine = common.machine_description()
    return "\n".join([
        SECTION_BEGIN,
        "## Long takes (`benchmarks/long_takes.py`)",
        "",
        "Whole processes, file to file, one torch thread; wall time from start to exit (torch's "
        "import included; every module byte-compiled, as an installed package has them) and peak "
        "resident memory. Takes: corpus files end to end with "
        "Pose-NDF noise (σ = 0.10 rad); npz at 30 Hz, BVH at 120 Hz on the SMPL skeleton. "
        "*x scipy pass*: the run's wall time over that of the same file read, smoothed with "
        "scipy's Savitzky–Golay (9 frames, order 2) and written by the same reader and writer. "
        "*before*: the same runs with `--baseline` (another tree's `mdvae_cli`), alternating "
        "with this tree's; *output vs before*: the largest difference between the two outputs "
        "(npz: poses in rad and trans in m; BVH: channel values as written).",
        "",
        table(rows),
        "",
        f"Machine: {machine['cpu']}, {machine['cores usable by this process']} cores usable "
        f"(shared with other work), {machine['date']}. Command: "
        f"`python benchmarks/long_takes.py {' '.join(argv)}`.",
        SECTION_END,
    ])  # fmt: skip


def readme_table(rows: list[Row]) -> str:
    """The README's short table: the default and view on the longest take of each format."""
    keep = []
    for fmt in dict.fromkeys(r.fmt for r in rows):
        longest = max(r.minutes for r in rows if r.fmt == fmt)
        keep += [r for r in rows if r.fmt == fmt and r.minutes == longest]
    return "\n".join([README_BEGIN, table(keep), README_END])


def save_rows(rows: list[Row], path: Path, argv: list[str]) -> None:
    """The rows and the command that measured them, as JSON (``--load`` reads it back)."""
    path.write_text(json.dumps({"argv": argv, "rows": [
        {"format": r.fmt, "minutes": r.minutes, "frames": r.frames, "run": r.kind,
         "seconds": r.now.seconds, "peak_mb": r.now.peak_mb, "page_mb": r.page_mb,
         "before_seconds": r.before and r.before.seconds,
         "before_peak_mb": r.before and r.before.peak_mb, "gap": r.gap}
        for r in rows
    ]}, indent=1))  # fmt: skip


def load_rows(path: Path) -> tuple[list[Row], list[str]]:
    """:func:`save_rows`'s file. -> (rows, the command line that measured them)"""
    data = json.loads(path.read_text())
    rows = [
        Row(d["format"], d["minutes"], d["frames"], d["run"], Run(d["seconds"], d["peak_mb"], ""),
            page_mb=d["page_mb"], gap=d["gap"],
            before=None if d["before_seconds"] is None
            else Run(d["before_seconds"], d["before_peak_mb"], ""))
        for d in data["rows"]
    ]  # fmt: skip
    return rows, data["argv"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 10, 30])
    parser.add_argument("--formats", nargs="+", choices=sorted(RATES), default=["npz", "bvh"])
    parser.add_argument("--runs", nargs="+", choices=["default", "refine", "view"],
                        default=["default", "refine", "view"])  # fmt: skip
    parser.add_argument("--corpus", default=str(REPO / "data" / "corpus" / "cmu"))
    parser.add_argument("--work", default="/tmp/mdvae_long_takes")
    parser.add_argument("--baseline", help="a tree with another mdvae_cli to compare with")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="runs of each (alternating with the baseline's): the median time",
    )
    parser.add_argument("--json", help="also save the rows here")
    parser.add_argument("--load", help="no runs: the rows saved by an earlier --json")
    parser.add_argument("--write", action="store_true",
                        help="update docs/benchmarks.md and README.md")  # fmt: skip
    args = parser.parse_args(argv)
    shown = sys.argv[1:] if argv is None else argv
    if args.load:
        rows, shown = load_rows(Path(args.load))
    else:
        if "view" in args.runs and "default" not in args.runs:
            args.runs = ["default", *args.runs]
        rows = measure(args)
    print(table(rows))
    if args.json:
        save_rows(rows, Path(args.json), shown)
    if args.write:
        common.write_section(REPO / "docs" / "benchmarks.md", section(rows, shown),
                             SECTION_BEGIN, SECTION_END)  # fmt: skip
        common.write_section(REPO / "README.md", readme_table(rows), README_BEGIN, README_END)


if __name__ == "__main__":
    main()
