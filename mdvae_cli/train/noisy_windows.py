"""The windows ``mdvae fit-dataset`` fits the inference networks to: noisy files at 30 Hz, with
their mirror images, short takes cut from them and copies with random holes, all still only
noisy data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.infer.window_groups import WindowGroup, make_windows
from mdvae_cli.model.chunks import MODEL_FPS
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.motion.holes import random_holes, with_holes
from mdvae_cli.motion.mirror import mirror_motion
from mdvae_cli.motion.motion import Motion, slice_frames
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.train.corpus import load_training_motion


def concat_groups(groups: list[WindowGroup], length: int) -> WindowGroup | None:
    """The group of windows of exactly ``length`` frames (training uses full windows only)."""
    same = [g for g in groups if g.yn.shape[1] == length]
    return same[0] if same else None


def load_noisy_windows(
    files: list[Path],
    denoiser: Denoiser,
    body: BodyModel,
    window: int,
    stride: int,
    mirror: bool = False,
    short_windows: tuple[int, ...] = (),
    short_share: float = 0.25,
    seed: int = 0,
    holes: float = 0.0,
) -> list[WindowGroup]:
    """The full-length windows of noisy files at 30 Hz (with ``mirror``, also those of every
    file's left-right mirror image: still only noisy data) as the first group, then one group
    of short takes per length of ``short_windows`` (:func:`short_takes`). ``holes``: also
    copies of that share of the takes with random holes (:func:`holed_copies`), as a group of
    their own after the first: the networks read the holes (``WindowGroup.seen``) while the
    likelihood scores the noisy frames hidden there, so that filling them is what the fit
    learns (still from noisy data alone)."""
    motions = [resample_motion(load_training_motion(f), MODEL_FPS) for f in files]
    if mirror:
        motions += [mirror_motion(m, body) for m in motions]
    groups = make_windows(motions, denoiser, body, window, stride)
    full = concat_groups(groups, window + 1)
    if full is None:
        raise InputError(f"no noisy motion of at least {window + 1} frames at 30 Hz found")
    out = [full]
    if holes > 0:
        holed, sources = holed_copies(motions, holes, seed)
        hidden = make_windows(holed, denoiser, body, window, stride, scored=sources)
        out += [g for g in hidden if g.yn.shape[1] == window + 1]
    if short_windows:
        count = max(1, round(short_share * len(full) / len(short_windows)))
        for length in short_windows:
            clips = short_takes(motions, length, count, seed)
            out += make_windows(clips, denoiser, body, window, stride)
    return out


def short_takes(motions: list[Motion], length: int, count: int, seed: int) -> list[Motion]:
    """``count`` clips of ``length`` frames cut from the motions: every motion is cut into
    consecutive clips from a seeded random start, then ``count`` of all of them are drawn
    (seeded, without replacement; all when there are fewer)."""
    gen = np.random.default_rng([seed, length])
    pieces = []
    for mi, m in enumerate(motions):
        if m.num_frames < length:
            continue
        first = int(gen.integers(0, length))
        pieces += [(mi, s) for s in range(first, m.num_frames - length + 1, length)]
    pick = gen.permutation(len(pieces))[:count]
    return [slice_frames(motions[mi], s, s + length) for mi, s in (pieces[i] for i in sorted(pick))]


def holed_copies(
    motions: list[Motion], share: float, seed: int
) -> tuple[list[Motion], list[Motion]]:
    """Copies of a seeded ``share`` of the motions (every motion once per whole unit of it,
    then a random draw for the fraction) with random holes (``motion.holes.random_holes``),
    their placeholders slerp / lerp as a file's holes are read; and the motions they copy."""
    gen = np.random.default_rng([seed, 7])
    whole, part = divmod(share, 1.0)
    picks = [i for _ in range(int(whole)) for i in range(len(motions))]
    picks += sorted(gen.permutation(len(motions))[: round(part * len(motions))].tolist())
    holed = [with_holes(motions[i], random_holes(motions[i].num_frames, gen)) for i in picks]
    return holed, [motions[i] for i in picks]
