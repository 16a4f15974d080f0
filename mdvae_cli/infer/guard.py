"""The guard that keeps a denoised window from moving the motion further than its noise explains.

A denoiser that has never seen a kind of motion, or that gets only a few frames, can answer
with a motion further from the truth than the noisy input itself. Its distance from the input
tells: if the output is within the noise of the truth, the input is about one noise level away
from it (noise and error are independent, so E|x_hat - y|^2 = sigma^2 + error^2 < 2 sigma^2);
an output further than that is, in expectation, worse than the input. So each window's mean
squared distance between the output's and the input's joint rotations is compared with
``ratio`` times the input's own noise variance, estimated from the input alone (its second
differences in time: white noise of variance sigma^2 gives second differences of variance
6 sigma^2, and the median keeps real motion from inflating it much). A window past the guard
falls back to the input smoothed by a short local-line filter (Savitzky–Golay, up to 11
frames), which never strays far from the input; the caller is told which windows did.

Pure tensor math on canonical states (N, T, 138).
"""

from __future__ import annotations

import torch

from mdvae_cli.filters import savgol_smooth
from mdvae_cli.infer.input_noise import CHI2_MEDIAN
from mdvae_cli.model.chunks import MODEL_FPS
from mdvae_cli.model.state import POSE, ROOT
from mdvae_cli.motion.motion import Motion

#: a window falls back when its output is this many noise variances from its input
GUARD_RATIO = 2.0
#: ... and at least this far (rad, RMS over the rotations): on (nearly) clean input the noise
#: estimate is tiny and any correction would otherwise look large
GUARD_FLOOR = 0.03
_ROTATIONS = torch.tensor([*range(ROOT.start, ROOT.stop), *range(POSE.start, POSE.stop)])


def input_noise_variance(obs: torch.Tensor) -> torch.Tensor:
    """Each window's noise variance of the joint rotations (rad^2), from the input alone.

    obs: (N, T, 138) noisy states -> (N,); NaN for windows under 3 frames."""
    rot = obs[..., _ROTATIONS]
    if rot.shape[1] < 3:
        return rot.new_full((rot.shape[0],), float("nan"))
    d2 = rot[:, 2:] - 2 * rot[:, 1:-1] + rot[:, :-2]
    return (d2**2).flatten(1).median(dim=1).values / (6.0 * CHI2_MEDIAN)


def moved(x_hat: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
    """Mean squared distance of the output's joint rotations from the input's (rad^2).

    x_hat, obs: (N, T, 138) -> (N,)"""
    return ((x_hat[..., _ROTATIONS] - obs[..., _ROTATIONS]) ** 2).flatten(1).mean(dim=1)


def past_guard(
    x_hat: torch.Tensor,
    obs: torch.Tensor,
    ratio: float = GUARD_RATIO,
    floor: float = GUARD_FLOOR,
) -> torch.Tensor:
    """Which windows moved further than their noise explains.  (N, T, 138) x2 -> (N,) bool"""
    distance = moved(x_hat, obs)
    noise = input_noise_variance(obs)
    return (distance > ratio * noise) & (distance > floor**2) & ~torch.isnan(noise)


def fallback_states(obs: torch.Tensor) -> torch.Tensor:
    """The input smoothed by a local line over up to 11 frames (shorter for a short window).

    obs: (N, T, 138) -> (N, T, 138); velocities are not smoothed (nothing reads them)."""
    T = obs.shape[1]
    window = min(11, T if T % 2 else T - 1)
    if window < 3:
        return obs.clone()
    smoothed = savgol_smooth(obs.transpose(0, 1).double().numpy(), window, 1)
    return torch.as_tensor(smoothed, dtype=obs.dtype).transpose(0, 1).contiguous()


def guard(x_hat: torch.Tensor, obs: torch.Tensor, ratio: float = GUARD_RATIO):
    """The outputs with every window past the guard replaced by its fallback, and which.

    x_hat, obs: (N, T, 138) -> ((N, T, 138), (N,) bool)"""
    bad = past_guard(x_hat, obs, ratio)
    if not bool(bad.any()):
        return x_hat, bad
    out = x_hat.clone()
    out[bad] = fallback_states(obs[bad])
    return out, bad


def fallback_stretches(
    fallbacks: list[tuple[int, int]], motions30: list[Motion], window: int
) -> dict[int, list[tuple[float, float]]]:
    """The guard's fallen-back windows (motion index, 30 Hz start) as merged stretches of
    seconds per motion (overlapping windows make one stretch)."""
    spans: dict[int, list[tuple[float, float]]] = {}
    for mi, start in fallbacks:
        n = min(window + 1, motions30[mi].num_frames)
        spans.setdefault(mi, []).append((start / MODEL_FPS, (start + n - 1) / MODEL_FPS))
    return {mi: merged_stretches(s) for mi, s in sorted(spans.items())}


def merged_stretches(stretches: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Stretches of seconds, sorted, those that touch or overlap made one."""
    out: list[tuple[float, float]] = []
    for a, b in sorted(stretches):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


GUARD_NOTE = "guard: "


def guard_note(stretches: list[tuple[float, float]], duration: float) -> str:
    """The note a motion gets for the guard's stretches (seconds) of its ``duration`` s."""
    seconds = sum(b - a for a, b in stretches)
    where = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in stretches)
    return (
        f"{GUARD_NOTE}{100 * min(seconds / max(duration, 1e-9), 1.0):.0f} % of the take ({where}) "
        "moved further from the input than its noise explains and is the input smoothed instead"
    )


def is_guard_note(note: str) -> bool:
    """Whether a motion's note is :func:`guard_note`'s."""
    return note.startswith(GUARD_NOTE)
