"""Long takes a piece of time at a time (``infer.time_pieces``): where the cuts fall, how
neighbouring pieces hand over, what the callbacks are told, and a long take denoised in
pieces against the same take denoised whole."""

from __future__ import annotations

import signal
import threading
import time

import numpy as np
import pytest
from conftest import motion_arrays

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.infer import time_pieces
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.infer.noise_blend import BlendReport
from mdvae_cli.infer.time_pieces import (
    denoise_in_pieces,
    fade_in,
    hand_over,
    plan_pieces,
)
from mdvae_cli.metrics import evaluate_pair
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.workers import map_in_order


def _take(T: int, fps: float = 30.0, seed: int = 3) -> Motion:
    a = motion_arrays(T=T, fps=fps, seed=seed)
    return Motion.from_poses(a["poses"], a["trans"], a["betas"], fps)


def test_a_short_take_is_one_piece():
    assert plan_pieces(np.ones(1200, bool), 30.0, piece=800) is None  # <= 1.5 pieces
    assert plan_pieces(np.ones(1201, bool), 30.0, piece=800) is not None


def test_pieces_cover_the_take_with_their_overlap():
    plan = plan_pieces(np.ones(4000, bool), 30.0, piece=1000, overlap_s=8.0, fade_s=4.0)
    assert plan.cuts == (0, 1000, 2000, 3000, 4000)
    assert plan.spans == ((0, 1240), (760, 2240), (1760, 3240), (2760, 4000))
    assert plan.fade == 120


def test_a_cut_moves_off_missing_frames():
    """The overlap about each cut (8 s each side) holds no missing frame: a hole near where a
    cut would fall pushes the cut to the nearest frame clear of it; a cut with none within a
    quarter piece is left out (its neighbours grow)."""
    observed = np.ones(4000, bool)
    observed[1010:1030] = False  # a hole at the first cut
    observed[2900:3100] = False  # a long one over the third
    plan = plan_pieces(observed, 30.0, piece=1000, overlap_s=8.0, fade_s=4.0)
    for c in plan.cuts[1:-1]:
        assert observed[c - 240 : c + 240].all(), c
    assert plan.cuts == (0, 1010 - 240, 2000, 4000)
    # nothing observed anywhere near a cut: one piece
    assert plan_pieces(np.zeros(4000, bool), 30.0, piece=1000) is None


def test_fade_rises_smoothly_and_hands_over_symmetrically():
    w = fade_in(120)
    assert np.all(np.diff(w) > 0) and 0 < w[0] < 1e-3 and 1 - 1e-3 < w[-1] < 1
    np.testing.assert_allclose(w + w[::-1], 1.0, atol=1e-12)


def test_hand_over_slerps_from_one_result_to_the_other():
    n = 40
    before = np.zeros((n, 2, 3))
    after = np.zeros((n, 2, 3))
    after[:, 0, 2] = 1.0  # 1 rad about z on joint 0
    rot, trans = hand_over(before, after, np.zeros((n, 3)), np.ones((n, 3)))
    w = fade_in(n)
    np.testing.assert_allclose(rot[:, 0, 2], w, atol=1e-12)  # about one axis, the angle is lerped
    np.testing.assert_allclose(rot[:, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(trans, np.repeat(w[:, None], 3, axis=1), atol=1e-12)


def _workers(monkeypatch, n: int) -> None:
    """The pieces of a take run on ``n`` threads where they may run on every core, whatever
    the machine's cores."""

    def on_n(fn, items, workers=None, stop=None):
        return map_in_order(fn, items, n if workers is None else workers, stop)

    monkeypatch.setattr(time_pieces, "map_in_order", on_n)


def test_pieces_are_joined_with_callbacks_on_the_whole_take(monkeypatch):
    """A stand-in denoiser that adds its piece's number to the translation and reports a
    fallback and a blend per piece: each piece's own frames carry its number, the hand-overs
    lie between, the fallbacks come back in the take's seconds (clipped to what each piece
    owns), the blend shares weighted by the frames each owns, the progress counted over
    all the runs, and a short take beside the long one goes to the denoiser as it came."""
    _workers(monkeypatch, 1)  # the stand-in counts its calls: one piece after the other
    long, short = _take(3000), _take(200, seed=4)
    calls = []

    def run(ms, loops, progress, on_fallback, on_blend, piece=False):
        calls.append([m.num_frames for m in ms])
        pieces.append(piece)
        out = []
        for i, m in enumerate(ms):
            k = len(calls) - 1
            out.append(m.with_body(trans=m.trans + k))
            on_fallback(i, 1.0, 2.0)  # seconds 1-2 of what it was given
            on_blend(i, BlendReport(input_share=0.1 * k, spike_share=0.0))
            progress({"stage": "denoise", "step": 1, "steps": 2, "phase": "x"})
        return out

    fallbacks, blends, told, pieces, finished = [], {}, [], [], []

    def finish(joined, take):  # the whole take's last stage (the foot lock)
        finished.append((joined.num_frames, take is long))
        return joined

    out = denoise_in_pieces(
        [long, short], [False, False], run, told.append,
        lambda i, a, b: fallbacks.append((i, round(a, 6), round(b, 6))),
        lambda i, r: blends.setdefault(i, r), piece=1000, finish=finish,
    )  # fmt: skip
    assert calls == [[200], [1240], [1480], [1240]]  # the short one first, then each piece
    assert pieces == [False, True, True, True] and finished == [(3000, True)]
    np.testing.assert_array_equal(out[1].trans, short.trans)  # run 0: + 0
    shift = out[0].trans - long.trans
    np.testing.assert_allclose(shift[:940], 1.0)  # piece 0 is run 1
    np.testing.assert_allclose(shift[1060:1940], 2.0)
    np.testing.assert_allclose(shift[2060:], 3.0)
    assert np.all(np.diff(shift[940:1060, 0]) > 0) and np.all(np.diff(shift[1940:2060, 0]) > 0)
    np.testing.assert_allclose(out[0].joint_rotations, long.joint_rotations, atol=1e-12)
    # piece 0 was given frames 0-1239, piece 1 760-2239, piece 2 1760-2999: seconds 1-2 of
    # each is 1-2, 26.3-27.3 (piece 0 owns frames to 1000: 33.3 s) ...
    assert fallbacks == [(1, 1.0, 2.0), (0, 1.0, 2.0)]
    assert blends[1].input_share == 0.0
    np.testing.assert_allclose(blends[0].input_share, (0.1 * 1000 + 0.2 * 1000 + 0.3 * 1000) / 3000)
    # the short take's run, then the pieces' steps summed (they may go on side by side)
    assert [t["step"] for t in told] == [1, 3, 4, 5] and {t["steps"] for t in told} == {8}


def test_ctrl_c_stops_the_pieces_side_by_side_at_their_next_step(monkeypatch):
    """Ctrl-C (SIGINT to the main thread, waiting for the pieces) while two pieces refine side
    by side: each ends at the next step it tells, not after its 500 (5 s each)."""
    _workers(monkeypatch, 2)
    told: list[int] = []
    main = threading.main_thread().ident

    def run(ms, loops, progress, on_fallback, on_blend, piece=False):
        for step in range(1, 501):
            time.sleep(0.01)
            progress({"stage": "refine", "step": step, "steps": 500})
            told.append(step)
            if len(told) == 10:
                signal.pthread_kill(main, signal.SIGINT)
        return list(ms)

    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        denoise_in_pieces([_take(2000)], [False], run, None, None, None, piece=1000)
    assert time.perf_counter() - start < 2.0 and len(told) < 30


@pytest.mark.parametrize(("pieces", "side"), [(3, 4), (5, 4), (3, 2), (2, 2)])
def test_pieces_side_by_side_join_as_one_after_the_other(monkeypatch, pieces, side):
    """On two threads the pieces of a take of at most ``side_by_side`` pieces go on side by
    side (a longer one's one after the other) and finish in any order; the joined take, the
    fallbacks and the blend shares are those of one piece after the other, told in the
    pieces' order, and each stage's progress only rises."""
    T = 1000 * pieces
    long = _take(T).with_body(trans=np.stack([np.arange(T) / 1000, np.zeros(T), np.zeros(T)], 1))
    threads = set()

    def run(ms, loops, progress, on_fallback, on_blend, piece=False):
        (m,) = ms
        threads.add(threading.get_ident())
        lo = int(round(m.trans[0, 0] * 1000))  # the stand-in take's x is its frame / 1000
        time.sleep(0.05 if lo == 0 else 0.0)  # the first piece finishes last
        for step in (1, 2):
            progress({"stage": "denoise", "step": step, "steps": 2})
        on_fallback(0, 0.0, m.num_frames / m.fps)  # all of it: each piece tells what it owns
        on_blend(0, BlendReport(input_share=lo / 1e4, spike_share=0.0))
        return [m.with_body(trans=m.trans + lo)]

    results = []
    for n in (1, 2):
        _workers(monkeypatch, n)
        threads.clear()
        falls, blends, told = [], [], []

        def fell(i, a, b, falls=falls):
            falls.append((round(a, 6), round(b, 6)))

        def blended(i, r, blends=blends):
            blends.append(r)

        out = denoise_in_pieces([long], [False], run, told.append, fell, blended, piece=1000,
                                side_by_side=side)  # fmt: skip
        results.append((out[0], falls, blends, told, len(threads)))
    (one, falls1, blends1, _, _), (two, falls2, blends2, told2, used) = results
    np.testing.assert_array_equal(two.trans, one.trans)
    np.testing.assert_array_equal(two.joint_rotations, one.joint_rotations)
    assert falls2 == falls1 and len(falls1) == pieces
    assert [b.input_share for b in blends2] == [b.input_share for b in blends1]
    assert used == (2 if pieces <= side else 1)
    steps = [t["step"] for t in told2]
    assert steps == sorted(steps) and steps[-1] == 2 * pieces and told2[-1]["steps"] == 2 * pieces


@pytest.mark.parametrize(("refine", "side"), [(0, "SIDE_BY_SIDE_PIECES"),
                                              (5, "SIDE_BY_SIDE_REFINED")])  # fmt: skip
def test_refined_pieces_go_side_by_side_on_shorter_takes(monkeypatch, shipped, refine, side):
    """Refinement's pieces hold more memory: ``denoise`` lets fewer of them go at once."""
    import mdvae_cli.infer.denoise_settings as ds

    seen = []
    monkeypatch.setattr(ds, "denoise_in_pieces", lambda ms, *a, side_by_side, **k:
                        seen.append(side_by_side) or ms)  # fmt: skip
    denoise([_take(40)], DenoiseSettings(refine_steps=refine, rest_pose=False), *shipped)
    assert seen == [getattr(time_pieces, side)]
    assert time_pieces.SIDE_BY_SIDE_REFINED < time_pieces.SIDE_BY_SIDE_PIECES


@pytest.fixture(scope="module")
def shipped():
    denoiser, _ = load_denoiser(None)
    return denoiser, BodyModel(builtin_body_model())


def test_a_long_take_in_pieces_is_as_clean_as_the_take_whole(shipped, monkeypatch):
    """``denoise`` cuts a take longer than 1.5 pieces (here 800 frames, 80 s of a 30 Hz take
    in 3 pieces) and joins the results: what each piece estimates from its own frames (the
    noise, the floor) moves the result a little, not its accuracy (measured: 3.283 cm V2V
    whole, 3.306 in pieces, 8.77 noisy; rotations 0.0095 rad apart at the median)."""
    clean = _take(2400)
    noisy = add_pose_noise(clean, 0.1, np.random.default_rng(0))
    whole = denoise([noisy], DenoiseSettings(), *shipped)[0]
    monkeypatch.setattr(time_pieces, "PIECE_FRAMES", 800)
    blends = []
    settings = DenoiseSettings()
    pieces = denoise([noisy], settings, *shipped, on_blend=lambda i, r: blends.append(r))[0]
    body = shipped[1]
    err = {n: evaluate_pair(clean, m, body).v2v_cm for n, m in
           (("noisy", noisy), ("whole", whole), ("pieces", pieces))}  # fmt: skip
    assert err["pieces"] < 1.03 * err["whole"] and err["pieces"] < 0.45 * err["noisy"], err
    gap = np.linalg.norm(whole.joint_rotations - pieces.joint_rotations, axis=-1)
    assert np.median(gap) < 0.02, np.median(gap)
    assert len(blends) == 1 and pieces.num_frames == noisy.num_frames
    assert not np.array_equal(pieces.joint_rotations, whole.joint_rotations)  # it did cut


def test_the_benchmark_take_is_continuous_and_on_one_floor(tmp_path):
    """``benchmarks/time_pieces.py`` makes its long take from files end to end: each one's
    root starts where the last one ended, its feet on the same floor; a take against itself
    is 0 cm off."""
    from benchmarks.time_pieces import floor_height, frame_errors, long_take
    from mdvae_cli.formats.npz_io import save_motion

    body = BodyModel(builtin_body_model())
    files = []
    for i in range(2):
        m = _take(90, seed=i)
        m = m.with_body(trans=m.trans + np.array([0.0, 0.0, 0.3 * i]))  # another floor
        files.append(tmp_path / f"{i}.npz")
        save_motion(m, files[-1])
    take = long_take(files, 150 / 30 / 60, 30.0, body)
    assert take.num_frames == 150
    np.testing.assert_allclose(take.trans[90, :2], take.trans[89, :2])  # no jump at the join
    first = Motion(take.root_orient[:90], take.pose_body[:90], take.trans[:90], take.betas, 30.0)
    second = Motion(take.root_orient[90:], take.pose_body[90:], take.trans[90:], take.betas, 30.0)
    assert abs(floor_height(first, body, take.betas)) < 1e-6
    assert abs(floor_height(second, body, take.betas)) < 0.02  # the second file cut at 60 frames
    v, j = frame_errors(take, take, body)
    assert v.shape == j.shape == (150,) and v.max() < 1e-6 and j.max() < 1e-4
