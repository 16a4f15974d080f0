"""The hole benchmark's bookkeeping (benchmarks/holes.py): which observed frames count as
beside a hole, and the pooled means its rows are made of."""

import numpy as np

from benchmarks.holes import near_hole, pooled


def test_near_hole_marks_observed_frames_within_reach_on_both_sides():
    missing = np.zeros(20, bool)
    missing[8:11] = True  # frames 8, 9, 10
    near = near_hole(missing, 2)
    assert np.flatnonzero(near).tolist() == [6, 7, 11, 12]
    assert not (near & missing).any()


def test_near_hole_with_two_holes_and_a_hole_at_the_start():
    missing = np.zeros(12, bool)
    missing[[0, 1, 9]] = True
    assert np.flatnonzero(near_hole(missing, 1)).tolist() == [2, 8, 10]


def test_pooled_weighs_every_frame_alike():
    errors = [np.array([1.0, 2.0, 3.0]), np.array([10.0])]
    where = [np.array([True, False, True]), np.array([True])]
    assert pooled(errors, where) == (1.0 + 3.0 + 10.0) / 3
