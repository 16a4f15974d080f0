"""Classical filters: exactness on polynomials, noise reduction, rotations across +-pi."""

import numpy as np
import pytest
import torch

from mdvae_cli.errors import InputError
from mdvae_cli.filters import (
    CACHE_FRAMES,
    correlate_frames,
    gaussian_coefficients,
    gaussian_filter_motion,
    gaussian_smooth,
    savgol_coefficients,
    savgol_filter_motion,
    savgol_smooth,
)
from mdvae_cli.geometry.rotations import rotvec_to_quat
from mdvae_cli.motion.motion import Motion

FILTERS = {
    "gaussian": lambda m: gaussian_filter_motion(m, 2.0),
    "savgol-1": lambda m: savgol_filter_motion(m, 9, 1),
    "savgol-3": lambda m: savgol_filter_motion(m, 11, 3),
}


def make_motion(T=80, root=None, pose=None, trans=None, extra_width=90, seed=0) -> Motion:
    rng = np.random.default_rng(seed)
    return Motion(
        root_orient=np.tile([1.2, -0.3, 0.4], (T, 1)) if root is None else root,
        pose_body=np.tile(rng.normal(0, 0.4, (1, 21, 3)), (T, 1, 1)) if pose is None else pose,
        trans=np.tile([0.1, 0.2, 0.9], (T, 1)) if trans is None else trans,
        betas=rng.normal(size=16),
        fps=30.0,
        pose_extra=rng.normal(size=(T, extra_width)),
    )


def rotation_angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Geodesic angle (radians) between axis-angle rotations.  (..., 3), (..., 3) -> (...)"""
    qa, qb = rotvec_to_quat(torch.as_tensor(a)), rotvec_to_quat(torch.as_tensor(b))
    dot = (qa * qb).sum(-1).abs().clamp(max=1.0)
    return (2 * torch.acos(dot)).numpy()


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_constant_motion_is_unchanged_and_layout_kept(name):
    motion = make_motion()
    before = {k: getattr(motion, k).copy() for k in ("root_orient", "pose_body", "trans")}
    out = FILTERS[name](motion)
    assert out.num_frames == motion.num_frames and out.fps == motion.fps
    assert out.root_orient.shape == (80, 3) and out.pose_body.shape == (80, 21, 3)
    np.testing.assert_allclose(out.root_orient, motion.root_orient, atol=1e-12)
    np.testing.assert_allclose(out.pose_body, motion.pose_body, atol=1e-12)
    np.testing.assert_allclose(out.trans, motion.trans, atol=1e-12)
    np.testing.assert_array_equal(out.pose_extra, motion.pose_extra)  # hands untouched
    np.testing.assert_array_equal(out.betas, motion.betas)
    for k, v in before.items():  # the input is not modified
        np.testing.assert_array_equal(getattr(motion, k), v)


def test_savgol_coefficients_match_the_tabulated_values():
    # Savitzky & Golay (1964): quadratic/cubic, 5 points: (-3, 12, 17, 12, -3) / 35
    np.testing.assert_allclose(savgol_coefficients(5, 2), np.array([-3, 12, 17, 12, -3]) / 35)
    np.testing.assert_allclose(savgol_coefficients(5, 3), savgol_coefficients(5, 2), atol=1e-14)
    np.testing.assert_allclose(savgol_coefficients(7, 1), np.full(7, 1 / 7))
    g = gaussian_coefficients(1.5)
    assert g.shape == (13,) and g.sum() == pytest.approx(1.0) and np.argmax(g) == 6


@pytest.mark.parametrize("window, order", [(5, 1), (9, 2), (15, 3), (21, 4)])
def test_savgol_reproduces_linear_translation_exactly_edges_included(window, order):
    t = np.arange(60.0)[:, None]
    trans = np.array([0.1, -0.2, 0.9]) + t * np.array([0.03, 0.01, -0.002])
    out = savgol_filter_motion(make_motion(T=60, trans=trans), window, order)
    np.testing.assert_allclose(out.trans, trans, atol=1e-10)


@pytest.mark.parametrize("window, order", [(7, 2), (15, 3), (31, 4)])
def test_savgol_reproduces_quadratics_exactly(window, order):
    t = np.arange(70.0)
    x = np.stack([0.5 - 0.2 * t + 0.01 * t**2, 0.003 * t**2, 1 + 0 * t], axis=1)
    np.testing.assert_allclose(savgol_smooth(x, window, order), x, atol=1e-9)


def test_gaussian_keeps_linear_translation_and_biases_quadratics_as_predicted():
    t = np.arange(60.0)[:, None]
    trans = np.array([0.1, -0.2, 0.9]) + t * np.array([0.03, 0.01, -0.002])
    out = gaussian_filter_motion(make_motion(T=60, trans=trans), 2.0)
    r = 8  # 4 sigma: the plain convolution region
    np.testing.assert_allclose(out.trans[r:-r], trans[r:-r], atol=1e-12)
    # at the ends the kernel is cut and a weighted line is fitted: a line is kept there too
    np.testing.assert_allclose(out.trans, trans, atol=1e-10)
    # a quadratic a t^2 gains a * (discrete kernel variance) inside
    c = gaussian_coefficients(2.0)
    var = float(np.sum(c * np.arange(-r, r + 1) ** 2))
    x = 0.01 * np.arange(60.0) ** 2
    np.testing.assert_allclose(gaussian_smooth(x, 2.0)[r:-r], x[r:-r] + 0.01 * var, atol=1e-12)


@pytest.mark.parametrize(
    "smooth, expected",
    [
        # order 0/1: a box filter, variance / W
        (lambda x: savgol_smooth(x, 9, 1), 1 / np.sqrt(9)),
        # order 2/3, W = 2m + 1: centre weight 3(3m^2 + 3m - 1) / ((2m+3)(2m+1)(2m-1))
        (lambda x: savgol_smooth(x, 11, 2), np.sqrt(3 * (75 + 15 - 1) / (13 * 11 * 9))),
        # Gaussian: sum of squared weights ~ 1 / (2 sigma sqrt(pi))
        (lambda x: gaussian_smooth(x, 3.0), np.sqrt(1 / (2 * 3.0 * np.sqrt(np.pi)))),
    ],
)
def test_white_noise_std_drops_by_the_expected_factor(smooth, expected):
    noise = np.random.default_rng(1).normal(0.0, 0.2, size=(20000, 4))
    ratio = smooth(noise)[50:-50].std() / noise[50:-50].std()
    assert ratio == pytest.approx(expected, rel=0.04)


def one_axis_rotation(angles: np.ndarray, axis, wrap: bool) -> np.ndarray:
    """(T,) angles about a fixed axis -> (T, 3) axis-angles, wrapped into [0, pi] or not."""
    n = np.asarray(axis, float) / np.linalg.norm(axis)
    if wrap:  # the usual convention: past pi the vector flips to (2 pi - angle) about -n
        angles = np.where(angles > np.pi, angles - 2 * np.pi, angles)
    return angles[:, None] * n


@pytest.mark.parametrize("name", sorted(FILTERS))
@pytest.mark.parametrize("wrap", [True, False])
def test_constant_speed_rotation_across_pi_is_preserved(name, wrap):
    T = 90
    angles = 2.4 + 0.02 * np.arange(T) + 0.001  # crosses pi around frame 37, never exactly pi
    root = one_axis_rotation(angles, [0.3, -0.5, 0.8], wrap)
    pose = np.tile(one_axis_rotation(angles, [1.0, 0.2, 0.0], wrap)[:, None], (1, 21, 1))
    motion = make_motion(T=T, root=root, pose=pose)
    out = FILTERS[name](motion)
    # symmetric kernels scale a rotation at constant speed without delaying it: exact inside
    np.testing.assert_allclose(out.root_orient[12:-12], root[12:-12], atol=1e-9)
    np.testing.assert_allclose(out.pose_body[12:-12], pose[12:-12], atol=1e-9)
    assert rotation_angle_between(out.root_orient, root).max() < 2e-3  # one-sided fits at ends
    # each frame stays on its input's axis-angle branch: no jump appears, none is removed
    np.testing.assert_allclose(out.root_orient, root, atol=3e-3)
    np.testing.assert_allclose(out.pose_body, pose, atol=3e-3)
    step = np.linalg.norm(np.diff(out.root_orient, axis=0), axis=1)
    assert (step > 1.0).sum() == (1 if wrap else 0)


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_noisy_rotations_stay_valid_and_get_closer_to_the_truth(name):
    T = 120
    t = np.arange(T)[:, None, None] / 30.0
    rng = np.random.default_rng(3)
    clean = 0.8 * np.sin(2 * np.pi * 0.5 * t + rng.uniform(0, 6, (1, 21, 3)))
    clean[:, 0] += np.pi * np.array([0.0, 0.0, 0.98])  # a joint near pi: signs flip often
    noisy = clean + rng.normal(0, 0.15, clean.shape)
    motion = make_motion(T=T, root=noisy[:, 0], pose=noisy[:, 1:])
    out = FILTERS[name](motion)
    smoothed = np.concatenate([out.root_orient[:, None], out.pose_body], axis=1)
    assert np.isfinite(smoothed).all()
    assert np.linalg.norm(smoothed, axis=-1).max() < 2 * np.pi
    before = rotation_angle_between(noisy, clean).mean()
    after = rotation_angle_between(smoothed, clean).mean()
    assert after < 0.7 * before, (before, after)


def test_motions_shorter_than_the_window_keep_their_length():
    for T in (2, 3, 6):
        t = np.arange(float(T))[:, None]
        trans = 0.1 * t + np.array([0.0, 0.0, 0.9])
        motion = make_motion(T=T, trans=trans)
        for out in (savgol_filter_motion(motion, 31, 3), gaussian_filter_motion(motion, 5.0)):
            assert out.num_frames == T and out.pose_extra.shape == (T, 90)
            np.testing.assert_allclose(out.trans, trans, atol=1e-10)
    assert gaussian_smooth(np.ones((1, 3)), 2.0).shape == (1, 3)


@pytest.mark.parametrize(
    "call",
    [
        lambda m: savgol_filter_motion(m, 8, 2),
        lambda m: savgol_filter_motion(m, 7, 7),
        lambda m: savgol_filter_motion(m, 7, -1),
        lambda m: gaussian_filter_motion(m, -1.0),
        lambda m: gaussian_filter_motion(m, float("nan")),
    ],
)
def test_bad_parameters_raise_input_error(call):
    with pytest.raises(InputError):
        call(make_motion(T=20))


def test_zero_sigma_is_the_identity():
    motion = make_motion(T=20, trans=np.random.default_rng(0).normal(size=(20, 3)))
    np.testing.assert_array_equal(gaussian_filter_motion(motion, 0.0).trans, motion.trans)


def test_end_frames_match_a_direct_local_fit_for_any_length():
    from mdvae_cli.filters import local_poly_coefficients

    x = np.random.default_rng(0).normal(size=(40, 5))
    for T, window, order in ((40, 11, 2), (7, 11, 1), (12, 5, 3)):
        half, out = window // 2, savgol_smooth(x[:T], window, order)
        for t in range(T):  # the window slides inward at the ends
            lo = min(max(t - half, 0), max(T - window, 0))
            idx = np.arange(lo, min(lo + window, T))
            expected = local_poly_coefficients(idx, order, t) @ x[idx]
            np.testing.assert_allclose(out[t], expected, atol=1e-12)


# --------------------------------------------------------------------------------------------
# One-Euro


def test_one_euro_with_beta_0_is_a_first_order_low_pass():
    from mdvae_cli.filters import one_euro_smooth

    fps, fc = 30.0, 2.0
    x = np.r_[np.zeros(5), np.ones(40)]
    y = one_euro_smooth(x, fps, fc, 0.0)
    a = 1 / (1 + fps / (2 * np.pi * fc))
    expected = np.r_[np.zeros(5), 1 - (1 - a) ** np.arange(1, 41)]
    np.testing.assert_allclose(y, expected, atol=1e-12)


def test_one_euro_is_causal_keeps_constants_and_lags_less_with_beta():
    from mdvae_cli.filters import one_euro_smooth

    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 3))
    y = one_euro_smooth(x, 30.0, 1.0, 0.5)
    x2 = x.copy()
    x2[30:] += 5.0
    np.testing.assert_array_equal(one_euro_smooth(x2, 30.0, 1.0, 0.5)[:30], y[:30])
    np.testing.assert_allclose(one_euro_smooth(np.full((20, 2), 3.0), 30.0, 1.0, 1.0), 3.0)
    ramp = np.arange(60.0)[:, None] * 0.1
    lag = lambda b: float(ramp[-1, 0] - one_euro_smooth(ramp, 30.0, 1.0, b)[-1, 0])  # noqa: E731
    assert lag(1.0) < lag(0.0)


def test_one_euro_motion_filter_and_its_parameter_checks():
    from mdvae_cli.filters import one_euro_filter_motion

    m = make_motion(T=40)
    out = one_euro_filter_motion(m, 1.5, 0.3)
    assert out.num_frames == 40 and out.fps == m.fps
    np.testing.assert_allclose(out.root_orient[0], m.root_orient[0], atol=1e-9)  # first frame
    for bad in ((0.0, 0.1), (1.0, -1.0), (float("nan"), 0.0)):
        with pytest.raises(InputError, match="One-Euro"):
            one_euro_filter_motion(m, *bad)


def test_gaussian_smoothing_at_some_frames_gives_the_whole_results_rows_there():
    """``at`` works out the smoothing at those frames alone (ends included), for plain signals
    and rotation tracks; the result is the whole smoothing's rows there."""
    from mdvae_cli.filters import gaussian_smooth, smooth_rotvecs

    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=(101, 4, 3)), 0)
    frames = np.array([0, 1, 5, 6, 7, 50, 94, 99, 100])
    np.testing.assert_allclose(gaussian_smooth(x, 2.5, at=frames), gaussian_smooth(x, 2.5)[frames],
                               atol=1e-12)  # fmt: skip
    np.testing.assert_array_equal(gaussian_smooth(x, 0.0, at=frames), x[frames])
    rot = np.cumsum(rng.normal(0, 0.3, size=(101, 4, 3)), 0)  # runs past pi

    def smooth(q):
        return gaussian_smooth(q, 2.5)

    def smooth_at(q):
        return gaussian_smooth(q, 2.5, at=frames)

    np.testing.assert_allclose(smooth_rotvecs(rot, smooth_at, at=frames),
                               smooth_rotvecs(rot, smooth)[frames], atol=1e-12)  # fmt: skip


def test_the_model_rate_take_smooths_only_the_frames_it_samples_and_matches_smoothing_all():
    """A faster take at 30 Hz: the Gaussian worked out only at the frames the samples read
    gives what smoothing every frame and then resampling gives (whole and fractional ratios)."""
    from mdvae_cli.filters import gaussian_filter_motion
    from mdvae_cli.infer.native_rate import to_model_rate
    from mdvae_cli.motion.motion import Motion
    from mdvae_cli.motion.resample import resample_motion

    rng = np.random.default_rng(4)
    for fps, T in ((120.0, 243), (100.0, 207), (50.0, 61)):
        rv = np.cumsum(rng.normal(0, 0.1, (T, 22, 3)), 0)
        trans = np.cumsum(rng.normal(0, 0.01, (T, 3)), 0)
        m = Motion(root_orient=rv[:, 0], pose_body=rv[:, 1:], trans=trans, betas=np.zeros(10),
                   fps=fps)  # fmt: skip
        got = to_model_rate(m)
        want = resample_motion(gaussian_filter_motion(m, 0.4 * fps / 30.0), 30.0)
        assert got.num_frames == want.num_frames and got.fps == 30.0
        for a, b in ((got.root_orient, want.root_orient), (got.pose_body, want.pose_body),
                     (got.trans, want.trans)):  # fmt: skip
            np.testing.assert_allclose(a, b, atol=1e-10)


def test_the_smoothers_convolve_a_piece_at_a_time_with_the_same_result(monkeypatch):
    """Long takes are convolved a piece of frames at a time (in cache): the same values as in
    one pass, ends included."""
    import mdvae_cli.filters as f

    x = np.cumsum(np.random.default_rng(6).normal(size=(3001, 4, 3)), 0)
    monkeypatch.setattr(f, "CACHE_FRAMES", 10**9)
    whole = (f.gaussian_smooth(x, 2.5), f.savgol_smooth(x, 9, 2))
    monkeypatch.setattr(f, "CACHE_FRAMES", 500)
    np.testing.assert_array_equal(f.gaussian_smooth(x, 2.5), whole[0])
    np.testing.assert_array_equal(f.savgol_smooth(x, 9, 2), whole[1])


@pytest.mark.parametrize("T", [0, 2, 7, 8, CACHE_FRAMES + 11])
def test_correlate_frames_is_the_weighted_sum_of_the_frames_ahead(T):
    """An uneven kernel (no symmetry to hide a flip), frames across a cache block's edge and
    channels of any shape: each row is sum_k kernel[k] x[t + k], to rounding."""
    rng = np.random.default_rng(T)
    x = rng.normal(size=(T, 3, 2))
    kernel = np.array([0.5, -1.0, 2.0, 0.25, 3.0, -0.75, 1.5])
    n = max(T - len(kernel) + 1, 0)
    want = np.zeros((n, 3, 2))
    for k, w in enumerate(kernel):
        want += w * x[k : k + n]
    got = correlate_frames(x, kernel)
    assert got.shape == (n, 3, 2)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
