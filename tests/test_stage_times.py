"""``benchmarks/stage_times.py``: its table sums the chunked stages and keeps the others."""

from __future__ import annotations

from benchmarks import stage_times


def test_the_table_keeps_stages_in_order_and_sums_the_chunks():
    log = [
        ("write_file", 5.0, 2.0, "MainThread"),
        ("read_file", 1.0, 3.0, "MainThread"),
        ("solve_frames", 1.1, 0.5, "ThreadPoolExecutor-0_0"),
        ("solve_frames", 1.2, 0.7, "ThreadPoolExecutor-0_1"),
    ]
    lines = stage_times.table(log, every_chunk=False).splitlines()
    assert lines[2].startswith("| read_file | 1.00 | 3.00 |")
    assert lines[3].startswith("| write_file | 5.00 | 2.00 |")
    # two chunks, 1.2 s of their own, from 1.1 to 1.9 s
    assert lines[4] == "| solve_frames: 2 chunks, 1.20 s of their own | 1.10 | 0.80 | workers |"
    assert lines[-1].startswith("| the whole process |")
    every = stage_times.table(log, every_chunk=True).splitlines()
    assert sum(line.startswith("| solve_frames |") for line in every) == 2
