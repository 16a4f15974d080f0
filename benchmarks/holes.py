"""Holes: frames and joints a take is missing, filled by ``mdvae denoise`` and by what studio
tools do (slerp / lerp between the hole's ends, a cubic spline through the take, a pattern
fill from a matching stretch of the take).

On the corpus's ``test`` and ``unseen_test`` clips (150 frames at 30 Hz), clean (a studio
take that lost markers) and with Pose-NDF noise sigma = 0.10 rad (a noisy estimate): one hole
per clip of 5, 15, 30 or 60 frames (every joint), or one limb (arm or leg, three joints)
missing for 45 frames (1.5 s). Each row is V2V (cm, root-relative) on the filled frames alone;
then V2V on the observed frames, of the input and of the default's output (the context
a fill starts from: where the denoised frames beside a hole are off by as much as the input's,
a fill cannot be much better than slerp between them); the last
rows are the default's V2V on the observed frames over its V2V on the same take
without the hole (1.00 = the hole costs the rest nothing), on all of them, on those within
:data:`NEAR_SECONDS` of the hole (where a long hole leaves the frames beside it with context on
one side only: the take is split there) and on those beyond it; and over its V2V on the same
observed frames when the hole is slerped over and the take denoised whole, as ``mdvae
denoise`` read a video track's missing frames before it read holes. The "--fill model" row is
what the networks themselves made of the hole (of one that splits the take, in its bridge:
``infer.bridge``; docs/model.md, "Networks that read holes"); ``--denoiser`` measures
another denoiser (``fit-dataset --holes`` networks, say).

With ``--noise video`` the clips carry video-like noise instead (``add-noise --preset
video``) and ``mdvae denoise`` runs its video settings row (``--input-kind video``).

    python benchmarks/holes.py [--clips 12] [--clip-frames 150] [--denoiser RUN]
                               [--noise pose-ndf|video] [--write]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.export import DEFAULT_CHUNK_FRAMES, pose_motion_chunks
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.metrics import v2v
from mdvae_cli.motion.holes import frame_holes, limb_holes, with_holes
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import VideoNoise, add_video_noise, file_rng
from mdvae_cli.motion.pattern import pattern_fill
from mdvae_cli.train.corpus import select_files

REPO = Path(__file__).resolve().parents[1]
CLIP_FRAMES = 150
HOLES = ((5, "frames"), (15, "frames"), (30, "frames"), (60, "frames"), (45, "limb"))
SIGMAS = (0.0, 0.10)
#: observed frames this close to a hole (seconds) have their own ratio row
NEAR_SECONDS = 0.5


def hole_masks(clips: list[Motion], length: int, kind: str) -> list[np.ndarray]:
    """One hole per clip, placed by a generator seeded with the clip's index."""
    out = []
    for i, m in enumerate(clips):
        rng = np.random.default_rng(1000 * length + i)
        make = frame_holes if kind == "frames" else limb_holes
        out.append(make(m.num_frames, length, 1, rng, margin=30))
    return out


def conditions(noise: str) -> list[tuple[str, Callable[[list[common.Clip]], list[Motion]], str]]:
    """Each split's tables: (what the table says of the noise, the noisy clips from the clean
    ones, the settings row ``mdvae denoise`` runs: ``--input-kind``)."""
    if noise == "video":

        def video(clips):
            return [add_video_noise(c.motion, VideoNoise(), file_rng(0, f"{c.name}@video"))
                    for c in clips]  # fmt: skip

        return [("video-like noise (`add-noise --preset video`; `--input-kind video`)", video,
                 "video")]  # fmt: skip
    return [
        (f"sigma = {s:g}",
         lambda clips, s=s: common.add_noise(clips, s, 0) if s > 0 else [c.motion for c in clips],
         "mocap")
        for s in SIGMAS
    ]  # fmt: skip


def methods(
    denoiser, body, input_kind: str = "mocap"
) -> dict[str, Callable[[list[Motion], list[np.ndarray]], list[Motion]]]:
    """The rows: each takes the noisy clips and their masks and returns the filled clips."""

    def classical(method: str):
        return lambda ms, masks: [with_holes(m, k, method) for m, k in zip(ms, masks, strict=True)]

    def pattern(ms, masks):
        holed = [with_holes(m, k) for m, k in zip(ms, masks, strict=True)]
        return [pattern_fill(h, with_holes(m, k, "spline"))[0]
                for h, m, k in zip(holed, ms, masks, strict=True)]  # fmt: skip

    def ours(**kw):
        settings = DenoiseSettings(input_kind=input_kind, **kw)
        return lambda ms, masks: denoise(
            [with_holes(m, k) for m, k in zip(ms, masks, strict=True)], settings, denoiser, body
        )

    return {
        "slerp / lerp": classical("slerp"),
        "cubic spline": classical("spline"),
        "cubic Hermite (ends fitted to 6 frames)": classical("hermite"),
        "pattern fill (the take's own frames; the spline where none matches)": pattern,
        "`mdvae denoise` (default)": ours(),
        "`--refine 50`": ours(refine_steps=50),
        "`--fill model` (the networks' own frames)": ours(fill="model"),
    }


def slerped_over(clips: list[Motion], masks: list[np.ndarray]) -> list[Motion]:
    """The clips with their holes slerped / lerped over and nothing marked missing: what
    ``mdvae denoise`` read before it read holes (a video track's missing frames were filled
    so, and an npz with NaN was refused)."""
    out = []
    for m, k in zip(clips, masks, strict=True):
        over = with_holes(m, k, "slerp")
        over.joint_mask = None
        out.append(over)
    return out


def posed(motion: Motion, body: BodyModel) -> tuple[torch.Tensor, torch.Tensor]:
    """Vertices (T, V, 3) and pelvis (T, 3) of a motion, float64."""
    chunks = list(pose_motion_chunks(motion, body, DEFAULT_CHUNK_FRAMES, vertices=True))
    verts = torch.cat([o.vertices for _, o in chunks]).double()
    return verts, torch.cat([o.joints[:, 0] for _, o in chunks]).double()


def frame_errors(gt: list[Motion], preds: list[Motion], body: BodyModel) -> list[np.ndarray]:
    """Per clip, V2V (cm, root-relative) of every frame.  -> [(T,)]"""
    out = []
    for g, p in zip(gt, preds, strict=True):
        vg, pg = posed(g, body)
        vp, pp = posed(p, body)
        out.append(100.0 * v2v(vp, vg, pp, pg).numpy())
    return out


def near_hole(missing: np.ndarray, frames: int) -> np.ndarray:
    """(T,) bool: observed frames at most ``frames`` away from a missing one.
    missing: (T,) bool, at least one True."""
    t = np.arange(len(missing))
    gone = np.flatnonzero(missing)
    distance = np.abs(t[:, None] - gone[None, :]).min(axis=1)
    return ~missing & (distance <= frames)


def pooled(errors: list[np.ndarray], where: list[np.ndarray]) -> float:
    """The mean of every clip's errors (T,) on its frames where ``where`` (T,) is True."""
    return float(np.concatenate([e[w] for e, w in zip(errors, where, strict=True)]).mean())


def split_table(
    split: str,
    n_clips: int,
    denoiser,
    body,
    log,
    clip_frames: int = CLIP_FRAMES,
    noise: str = "pose-ndf",
) -> str:
    corpus = REPO / "data" / "corpus"
    files = select_files([corpus], corpus / "split.json", split)
    clips = common.load_clips(files, corpus, clip_frames, max_clips=n_clips)
    gt = [c.motion for c in clips]
    cols = [f"{n} frames" if kind == "frames" else f"one limb, {n} frames" for n, kind in HOLES]
    parts = []
    for label, make_noisy, input_kind in conditions(noise):
        rows = methods(denoiser, body, input_kind)
        settings = DenoiseSettings(input_kind=input_kind)
        noisy = make_noisy(clips)
        whole = frame_errors(gt, denoise(noisy, settings, denoiser, body), body)
        given = frame_errors(gt, noisy, body)  # the input's own error: the fill's context
        table: dict[str, list[str]] = {k: [] for k in rows}
        seen_in: list[str] = []
        seen_out: list[str] = []
        kept: list[str] = []
        kept_near: list[str] = []
        kept_far: list[str] = []
        kept_slerped: list[str] = []
        for n, kind in HOLES:
            masks = hole_masks(noisy, n, kind)
            missing = [~k.all(axis=1) for k in masks]
            for name, run in rows.items():
                errs = frame_errors(gt, run(noisy, masks), body)
                table[name].append(f"{pooled(errs, missing):.2f}")
                if name.startswith("`mdvae denoise`"):
                    observed = [~m for m in missing]
                    obs, ref = pooled(errs, observed), pooled(whole, observed)
                    seen_in.append(f"{pooled(given, observed):.2f}")
                    seen_out.append(f"{obs:.2f}")
                    kept.append(f"{obs / ref:.3f}")
                    near = [near_hole(m, round(NEAR_SECONDS * 30)) for m in missing]
                    kept_near.append(f"{pooled(errs, near) / pooled(whole, near):.3f}")
                    far = [o & ~q for o, q in zip(observed, near, strict=True)]
                    kept_far.append(f"{pooled(errs, far) / pooled(whole, far):.3f}")
                    over = denoise(slerped_over(noisy, masks), settings, denoiser, body)
                    ref = pooled(frame_errors(gt, over, body), observed)
                    kept_slerped.append(f"{obs / ref:.3f}")
            log(f"{split} {label} {n} {kind}: " + ", ".join(
                f"{k[:14]} {v[-1]}" for k, v in table.items()))  # fmt: skip
        head = [f"V2V cm on the filled frames, {label}", *cols]
        body_rows = [[k, *v] for k, v in table.items()]
        body_rows.append(["V2V cm on the observed frames: the input", *seen_in])
        body_rows.append(["... the default's output", *seen_out])
        body_rows.append(["default on the observed frames / without the hole", *kept])
        body_rows.append(
            [f"... on those within {NEAR_SECONDS:g} s of the hole / without the hole", *kept_near]
        )
        body_rows.append(
            [f"... on those beyond {NEAR_SECONDS:g} s of the hole / without the hole", *kept_far]
        )
        body_rows.append(
            ["default on the observed frames / the hole slerped over and the take denoised whole",
             *kept_slerped]
        )  # fmt: skip
        parts.append(common.markdown_table(head, body_rows))
    return f"**{split}** ({len(clips)} clips of {clip_frames} frames at 30 Hz)\n\n" + "\n\n".join(
        parts
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clips", type=int, default=12, help="clips per split (spread evenly)")
    ap.add_argument("--splits", default="test,unseen_test")
    ap.add_argument("--clip-frames", type=int, default=CLIP_FRAMES, help="frames per clip (30 Hz)")
    ap.add_argument("--write", action="store_true",
                    help="write the section of docs/benchmarks.md (one per --noise)")  # fmt: skip
    ap.add_argument("--denoiser", help="denoiser checkpoint or folder (default: the shipped one)")
    ap.add_argument("--noise", choices=["pose-ndf", "video"], default="pose-ndf",
                    help="the clips clean and with Pose-NDF noise of 0.10 rad (the table in "
                         "docs/benchmarks.md), or with video-like noise")  # fmt: skip
    args = ap.parse_args(argv)
    if args.write and args.denoiser:
        ap.error("--write documents the shipped weights: leave out --denoiser")
    denoiser, body, log = common.shipped_models_and_log(args.denoiser)

    text = [
        split_table(s, args.clips, denoiser, body, log, args.clip_frames, args.noise)
        for s in args.splits.split(",")
    ]
    video = args.noise == "video"
    tag = "holes_video" if video else "holes"
    section = (
        f"<!-- {tag}:begin (written by benchmarks/holes.py) -->\n"
        + (
            "## Holes under video-like noise\n\n"
            if video
            else "## Holes (missing frames and joints)\n\n"
        )  # fmt: skip
        + "\n\n".join(text)
        + f"\n\n({common.cpu_model()}; `python benchmarks/holes.py --clips {args.clips}"
        + (f" --clip-frames {args.clip_frames}" if args.clip_frames != CLIP_FRAMES else "")
        + (" --noise video" if video else "")
        + "`)\n"
        + f"<!-- {tag}:end -->"
    )
    print(section)
    if args.write:
        common.write_section(REPO / "docs" / "benchmarks.md", section,
                             f"<!-- {tag}:begin", f"<!-- {tag}:end -->")  # fmt: skip


if __name__ == "__main__":
    main()
