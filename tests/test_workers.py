"""A long take's chunks worked on side by side (``mdvae_cli.workers``): the results in order,
bounded work in flight, failures where they belong, and the BVH path the same bit for bit on
one thread or several."""

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from mdvae_cli import workers
from mdvae_cli.infer.progress import Stopped, stoppable
from mdvae_cli.workers import map_in_order


@pytest.mark.parametrize("n", [1, 2, 3])
def test_results_come_in_the_items_order_whichever_finishes_first(n):
    def slow_first(k):
        time.sleep(0.02 * (5 - k))  # the first items finish last
        return k * k

    assert list(map_in_order(slow_first, range(6), workers=n)) == [k * k for k in range(6)]


def test_at_most_one_item_per_worker_runs_ahead_of_the_one_in_use():
    started, lock = [], threading.Lock()

    def work(k):
        with lock:
            started.append(k)
        return k

    ahead = []
    for k in map_in_order(work, range(20), workers=2):
        time.sleep(0.005)
        with lock:
            ahead.append(max(started) - k)
    assert max(ahead) <= 2 and len(started) == 20


def test_a_failure_comes_where_its_result_would_and_torch_threads_come_back():
    threads = torch.get_num_threads()
    seen = []

    def work(k):
        if k == 3:
            raise ValueError("chunk 3 is bad")
        return k

    with pytest.raises(ValueError, match="chunk 3"):
        for k in map_in_order(work, range(8), workers=2):
            assert torch.get_num_threads() == 1  # one torch thread per worker meanwhile
            seen.append(k)
    assert seen == [0, 1, 2]
    assert torch.get_num_threads() == threads


def test_a_consumer_that_stops_early_leaves_nothing_running():
    calls = []

    def work(k):
        calls.append(k)
        return k

    gen = map_in_order(work, range(100), workers=2)
    assert next(gen) == 0
    gen.close()
    n = len(calls)
    time.sleep(0.05)
    assert len(calls) == n <= 4


def test_a_consumer_that_leaves_tells_the_long_items_still_running_to_stop():
    """Ctrl-C while long items run side by side: ``stop`` is set before they are waited for,
    so that an item that looks at it ends at once instead of running its course."""
    stop = threading.Event()
    ended = []

    def long_item(k):
        for _ in range(500):  # 5 s unless told to stop
            if stop.is_set():
                ended.append(k)
                return None
            time.sleep(0.01)
        return k

    gen = map_in_order(lambda k: k if k == 0 else long_item(k), range(4), workers=2, stop=stop)
    assert next(gen) == 0
    t = time.perf_counter()
    gen.close()  # as an interrupt raised in the consumer closes it
    assert time.perf_counter() - t < 1.0 and stop.is_set() and ended


def test_refinement_side_by_side_ends_at_its_next_step_when_left():
    """A refinement's steps in a worker raise ``Stopped`` once its run is left."""
    stop = threading.Event()
    told = []
    tell = stoppable(told.append, stop)
    tell({"step": 1})
    stop.set()
    with pytest.raises(Stopped):
        tell({"step": 2})
    assert told == [{"step": 1}]
    with pytest.raises(Stopped):
        stoppable(None, stop)({"step": 3})


def test_the_worker_count_follows_torch(monkeypatch):
    monkeypatch.setattr(torch, "get_num_threads", lambda: 3)
    assert workers.worker_count() == 3


def test_a_bvh_read_and_written_back_in_chunks_side_by_side_is_the_same_bits(tmp_path, monkeypatch):
    """The pose solve and the way back, in chunks of 16 frames on one thread and on three:
    the same motion and the same channel values, bit for bit."""
    import mdvae_cli.retarget.retarget as retarget
    import mdvae_cli.retarget.way_back as way_back
    from mdvae_cli.formats.registry import read, write
    from mdvae_cli.retarget.pose_solve import frame_chunks
    from tests.test_bvh_out import write_rig

    path = write_rig(tmp_path / "take.bvh", T=90)
    monkeypatch.setattr(retarget, "frame_chunks", lambda n: frame_chunks(n, 16))
    monkeypatch.setattr(way_back.write_back_data, "__defaults__", (16, None))
    results = {}
    for n in (1, 3):
        monkeypatch.setattr(workers, "worker_count", lambda n=n: n)
        loaded = read(path)
        m = loaded.single()
        turned = m.with_body(m.root_orient, m.pose_body * 0.9, m.trans + 0.01)
        write(turned, tmp_path / f"back{n}.bvh", take=loaded.take)
        results[n] = (m.poses, m.trans, (tmp_path / f"back{n}.bvh").read_bytes())
    assert np.array_equal(results[1][0], results[3][0])
    assert np.array_equal(results[1][1], results[3][1])
    assert results[1][2] == results[3][2]


@pytest.mark.parametrize("n", [1, 2])
def test_each_finished_chunk_gives_its_memory_back(monkeypatch, n):
    """What the stage before let go of, at once, before the first chunk; then after each
    chunk, at most every ``TRIM_SECONDS``."""
    given = []
    monkeypatch.setattr(workers, "give_back_memory", lambda *every: given.append(every))
    assert list(map_in_order(lambda k: k, range(5), workers=n)) == list(range(5))
    assert given == [(0.0,)] + [()] * 5


def test_one_chunk_is_worked_on_in_place(monkeypatch):
    """A short take's one chunk: no pool, no hand-back of memory, the caller's thread."""
    import threading

    given, where = [], []
    monkeypatch.setattr(workers, "give_back_memory", lambda *every: given.append(every))
    assert list(map_in_order(lambda k: where.append(threading.get_ident()) or k, [7])) == [7]
    assert list(map_in_order(lambda k: k, range(0))) == []
    assert given == [] and where == [threading.get_ident()]


def test_memory_is_given_back_at_most_every_trim_seconds(monkeypatch):
    """A trim walks every heap and makes the next chunk fault its pages in again: chunks
    finishing within ``TRIM_SECONDS`` of the last trim give nothing back."""
    trims, clock = [], [100.0]
    monkeypatch.setattr(workers, "_TRIM", lambda pad: trims.append(pad))
    monkeypatch.setattr(workers, "_last_trim", [float("-inf")])
    monkeypatch.setattr(workers, "time", SimpleNamespace(monotonic=lambda: clock[0]))
    for dt in (0.0, 0.1, 0.1, 0.04, 0.02, 0.3):
        clock[0] += dt
        workers.give_back_memory()
    # at 100.0 (the first), 100.26 (0.26 after it), 100.56; not at 100.1, 100.2 or 100.24
    assert trims == [0, 0, 0]
