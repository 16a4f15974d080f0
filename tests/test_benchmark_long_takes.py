"""benchmarks/long_takes.py: takes made from a corpus, processes measured, rows saved and
read back, the sections written."""

from pathlib import Path

from benchmarks.long_takes import (
    README_BEGIN,
    README_END,
    SECTION_BEGIN,
    Row,
    Run,
    commands,
    load_rows,
    make_take,
    readme_table,
    run_process,
    save_rows,
    section,
    table,
    typical,
)
from mdvae_cli.formats.npz_io import load_motion

REPO = Path(__file__).resolve().parents[1]


def test_a_take_of_the_asked_length_from_a_corpus(tmp_path):
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    (corpus / "walk.npz").write_bytes((REPO / "examples" / "walk.npz").read_bytes())
    take = make_take(corpus, 0.1, 30.0, tmp_path / "take.npz")
    motion = load_motion(take)
    assert motion.num_frames == 180 and motion.fps == 30.0  # 79-frame walk, tiled
    out = tmp_path / "smooth.npz"
    run = run_process(commands("scipy", take, out), REPO, 1)
    assert run.seconds > 0 and run.peak_mb > 0
    assert load_motion(out).num_frames == 180


def test_rows_round_trip_and_the_sections(tmp_path):
    rows = [
        Row("npz", 1.0, 1800, "scipy", Run(1.0, 200.0, ""), before=Run(1.0, 200.0, "")),
        Row("npz", 1.0, 1800, "default", Run(2.0, 300.0, ""), before=Run(4.0, 310.0, ""),
            gap=0.0),
        Row("npz", 1.0, 1800, "view", Run(3.0, 250.0, ""), page_mb=0.4,
            before=Run(3.0, 250.0, "")),
    ]  # fmt: skip
    save_rows(rows, tmp_path / "rows.json", ["--minutes", "1"])
    again, argv = load_rows(tmp_path / "rows.json")
    assert argv == ["--minutes", "1"] and table(again) == table(rows)
    text = table(rows)
    assert (
        "| 1 min npz (30 Hz) | 1,800 | default | 2.0 | 900 | 300 | 2.00 | 4.0 | 310 | 2.00 | 0 |"
        in text
    )
    assert "view (page 0.4 MB, x1.50 the default)" in text
    assert section(rows, argv).startswith(SECTION_BEGIN)
    readme = readme_table(rows)
    assert readme.startswith(README_BEGIN) and readme.endswith(README_END)


def test_repeats_give_the_median_time_and_the_largest_peak():
    got = typical([Run(9.0, 100.0, "a"), Run(30.0, 120.0, "b"), Run(10.0, 110.0, "c")])
    assert (got.seconds, got.peak_mb, got.output) == (10.0, 120.0, "c")


def test_a_run_s_peak_is_its_own_memory_not_this_process_s():
    """wait4's ru_maxrss counts the parent's resident memory at the fork: a benchmark that had
    just made a long take quoted its own size for every run. The peak is the child's own."""
    import numpy as np

    held = np.ones(400 * 2**20 // 8)  # 400 MB resident here, in the parent
    small = run_process(["-c", "pass"], REPO, 1)
    big = run_process(["-c", "import numpy as np; x = np.ones(300 * 2**20 // 8)"], REPO, 1)
    assert held.sum() > 0
    assert small.peak_mb < 100, small.peak_mb
    assert 300 < big.peak_mb < 400, big.peak_mb
