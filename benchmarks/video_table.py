"""Benchmark: denoising video-pipeline-like estimates (``mdvae add-noise --preset video``).

    python benchmarks/video_table.py [--corpus data/corpus] [--max-clips 64] [--val-clips 32]
                                     [--split test|unseen_test] [--out docs/benchmarks.md]
                                     [--tune] [--quick]

Protocol. Test-split files (30 Hz; ``--split unseen_test``: the kinds of motion no training saw,
written to a section of their own) are cut into 60-frame clips (``--clip-frames``); every clip
gets the video-like noise (``motion.noise.VideoNoise``, the preset's defaults, a seed fixed per
clip). The classical filters (Gaussian, Savitzky-Golay, and the One-Euro filter video-mocap
tools use) are tuned by grid search on val clips with the same noise, for the lowest MPJPE.
Rows: the noisy input, each tuned filter, ``mdvae denoise`` with the settings it picks for video
inputs (``infer/input_kinds.py``), run as the command runs it
(``infer.denoise_settings.denoise``: the offset, the blend, the spike and hole fills, the foot
lock), the same without the offset (the paper's regression mode), and ``--refine 50
--outliers``. Columns: MPJPE (22 joints, world, cm), V2V (root-relative, cm), acceleration error
(m/s^2), foot skate (cm/s: the mean horizontal speed of the foot joints 7, 8, 10, 11 on the
frames where the ground truth has them in contact: within 5 cm of the clip's lowest foot height
and slower than 0.2 m/s) and frames/s (file to file, all test clips in one run). A row gives the
noisy input's slow parts alone (the same draws, no jitter and no events): the estimator's bias,
which no temporal method can tell from motion, so its MPJPE is about the best any of them can
reach. ``--tune`` also scores candidate settings for the "video" row on the val clips.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.export import pose_motion_chunks
from mdvae_cli.filters import gaussian_filter_motion, one_euro_filter_motion, savgol_filter_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.infer.input_kinds import INPUT_KINDS
from mdvae_cli.infer.settings import OUTLIER_DOF
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import PRESETS, add_video_noise, file_rng
from mdvae_cli.train.corpus import read_split

REPO = Path(__file__).resolve().parents[1]
SECTION_BEGIN = "<!-- video_table:begin (written by benchmarks/video_table.py) -->"
SECTION_END = "<!-- video_table:end -->"
GAUSSIAN_GRID = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
SAVGOL_GRID = tuple((w, p) for w in (7, 11, 15, 21, 31) for p in (1, 2, 3) if p < w - 1)
ONE_EURO_GRID = tuple(
    (c, b) for c in (0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0) for b in (0.0, 0.3, 1.0, 3.0, 10.0)
)
FEET = (7, 8, 10, 11)
Process = Callable[[list[Motion]], list[Motion]]


#: the preset's white parts and events set to zero: what is left is its slow bias, drawn exactly
#: as in the full noise (every part has its own stream)
SLOW_ONLY = {
    "pose_white": 0.0, "root_white": 0.0, "depth_white": 0.0, "lateral_white": 0.0,
    "swap_rate": 0.0, "turn_rate": 0.0, "spike_frac": 0.0,
}  # fmt: skip
ROW_SLOW = "Noisy input's slow bias alone"


def video_noisy(clips: Sequence[common.Clip], seed: int, slow_only: bool = False) -> list[Motion]:
    """The video preset's noise on every clip, seeded per clip name (``slow_only``: only its
    slow parts, the same draws)."""
    noise = PRESETS["video"].with_overrides(SLOW_ONLY if slow_only else {})
    return [add_video_noise(c.motion, noise, file_rng(seed, f"{c.name}@video")) for c in clips]


# --------------------------------------------------------------------------------------------
# metrics


def foot_skate(gt: np.ndarray, pred: np.ndarray, fps: float) -> tuple[float, int]:
    """Mean horizontal speed (m/s) of the predicted foot joints where the ground truth's are in
    contact. gt, pred: (T, 22, 3) joints, z up -> (speed summed over contacts, contacts)."""
    g, p = gt[:, FEET], pred[:, FEET]
    floor = g[..., 2].min()
    low = g[..., 2] < floor + 0.05
    g_speed = np.linalg.norm(np.diff(g[..., :2], axis=0), axis=-1) * fps
    contact = low[:-1] & low[1:] & (g_speed < 0.2)
    p_speed = np.linalg.norm(np.diff(p[..., :2], axis=0), axis=-1) * fps
    return float(p_speed[contact].sum()), int(contact.sum())


def joints(motion: Motion, body: BodyModel, betas: np.ndarray) -> np.ndarray:
    """The 22 body joints of ``motion`` posed with ``betas``.  -> (T, 22, 3)"""
    chunks = pose_motion_chunks(motion, body, vertices=False, betas=betas)
    return np.concatenate([o.joints.double().numpy() for _, o in chunks])


def evaluate(gt: Sequence[Motion], sets: dict[str, Sequence[Motion]], body: BodyModel) -> dict:
    """{set: {mpjpe_cm, v2v_cm, accel_error, accel, skate_cms}} frame-weighted over clips
    (foot skate over contact frames), every ground truth posed once."""
    per: dict[str, list] = {k: [] for k in sets}
    skate = {k: [0.0, 0] for k in [*sets, "Ground truth"]}
    for i, g in enumerate(gt):
        posed = common._pose(g, body, g.betas)
        jg = posed.joints.numpy()
        s, n = foot_skate(jg, jg, g.fps)
        skate["Ground truth"][0] += s
        skate["Ground truth"][1] += n
        for k, preds in sets.items():
            other = common._pose(preds[i], body, g.betas)
            per[k].append(common._compare(posed, other, g.fps))
            s, n = foot_skate(jg, other.joints.numpy(), g.fps)
            skate[k][0] += s
            skate[k][1] += n
    out = {}
    for k, results in per.items():
        r = common.mean_result(results)
        out[k] = {
            "mpjpe_cm": r.mpjpe_cm,
            "v2v_cm": r.v2v_cm,
            "accel_error": r.accel_error,
            "accel": r.accel_pred,
            "skate_cms": 100 * skate[k][0] / max(skate[k][1], 1),
        }
        out.setdefault("Ground truth", {"accel": r.accel_gt})
    out["Ground truth"]["skate_cms"] = (
        100 * skate["Ground truth"][0] / max(skate["Ground truth"][1], 1)
    )
    return out


def mpjpe_only(gt: Sequence[Motion], sets: dict[str, Sequence[Motion]], body: BodyModel) -> dict:
    """{set: MPJPE cm} (joints only: fast, for tuning)."""
    out = {k: 0.0 for k in sets}
    frames = 0
    for i, g in enumerate(gt):
        jg = joints(g, body, g.betas)
        frames += len(jg)
        for k, preds in sets.items():
            out[k] += np.linalg.norm(joints(preds[i], body, g.betas) - jg, axis=-1).mean(1).sum()
    return {k: 100 * v / frames for k, v in out.items()}


# --------------------------------------------------------------------------------------------
# methods


def tune_filters(val: Sequence[common.Clip], body: BodyModel, seed: int) -> dict:
    """The best parameters of each filter on the val clips: {filter: (params, MPJPE cm)}."""
    gt, noisy = [c.motion for c in val], video_noisy(val, seed)
    cands: dict = {}
    for s in GAUSSIAN_GRID:
        cands[("gaussian", s)] = common.LazyMap(lambda m, s=s: gaussian_filter_motion(m, s), noisy)
    for w, p in SAVGOL_GRID:
        cands[("savgol", (w, p))] = common.LazyMap(
            lambda m, w=w, p=p: savgol_filter_motion(m, w, p), noisy
        )
    for c, b in ONE_EURO_GRID:
        cands[("one_euro", (c, b))] = common.LazyMap(
            lambda m, c=c, b=b: one_euro_filter_motion(m, c, b), noisy
        )
    scores = mpjpe_only(gt, cands, body)
    best = {}
    for (name, params), score in scores.items():
        if name not in best or score < best[name][1]:
            best[name] = (params, score)
    return best


def filter_process(name: str, params) -> Process:
    if name == "gaussian":
        return lambda ms: [gaussian_filter_motion(m, params) for m in ms]
    if name == "savgol":
        return lambda ms: [savgol_filter_motion(m, *params) for m in ms]
    return lambda ms: [one_euro_filter_motion(m, *params) for m in ms]


def denoise_process(denoiser, body, kind="video", **options) -> Process:
    """``mdvae denoise`` as the command runs it on an input of ``kind`` (its settings row, the
    offset, the blend, the spike and hole fills, the foot lock); options: ``DenoiseSettings``'
    (``refine_steps``, ``lam``, ``offset``, ``trans_offset_std``: the command's options)."""
    settings = DenoiseSettings(input_kind=kind, **options)
    return lambda ms: denoise(ms, settings, denoiser, body)


def rows(best: dict, denoiser, body, steps: int) -> dict[str, Process]:
    labels = {
        "gaussian": "Gaussian filter σ = {} frames",
        "savgol": "Savitzky-Golay {}/{}",
        "one_euro": "One-Euro filter (min cutoff {} Hz, β {})",
    }
    out = {}
    for name, (params, _) in best.items():
        p = params if isinstance(params, tuple) else (params,)
        out[labels[name].format(*p)] = filter_process(name, params)
    out["`mdvae denoise` (video settings)"] = denoise_process(denoiser, body)
    out["`mdvae denoise --smooth 0` (its result not smoothed)"] = denoise_process(
        denoiser, body, smooth_s=0.0
    )
    out["`mdvae denoise --no-offset`"] = denoise_process(denoiser, body, offset=False)
    out[f"`mdvae denoise --refine {steps} --outliers`"] = denoise_process(
        denoiser, body, refine_steps=steps, lam=OUTLIER_DOF
    )
    return out


TUNE_CANDIDATES = {
    "mocap row (λ 0)": {"kind": "mocap"},
    "λ 10": {"kind": "mocap", "lam": 10.0},
    "λ 5": {"kind": "mocap", "lam": 5.0},
    "λ 3": {"kind": "mocap", "lam": 3.0},
    "no translation offset": {"kind": "mocap", "trans_offset_std": 0.0},
    "no offset": {"kind": "mocap", "offset": False},
    "video row, --smooth 0": {"kind": "video", "smooth_s": 0.0},
    "video row, --smooth 0.05": {"kind": "video", "smooth_s": 0.05},
    "video row, --smooth 0.067": {"kind": "video", "smooth_s": 0.067},
    "video row, --smooth 0.083": {"kind": "video", "smooth_s": 0.083},
}


def tune_kind(val: Sequence[common.Clip], denoiser, body, seed: int) -> dict:
    """Candidate settings for the video row, scored on the val clips."""
    gt, noisy = [c.motion for c in val], video_noisy(val, seed)
    sets = {
        name: denoise_process(denoiser, body, **opts)(noisy)
        for name, opts in TUNE_CANDIDATES.items()
    }
    return evaluate(gt, sets, body)


# --------------------------------------------------------------------------------------------
# report


def build(test, val, denoiser, body, steps, seed, log=print) -> tuple[dict, dict, dict]:
    log(f"tuning the filters on {len(val)} val clips")
    best = tune_filters(val, body, seed)
    gt, noisy = [c.motion for c in test], video_noisy(test, seed)
    sets, speed = {"Noisy input": noisy, ROW_SLOW: video_noisy(test, seed, slow_only=True)}, {}
    with tempfile.TemporaryDirectory() as tmp:
        files = common.write_motions(noisy, Path(tmp) / "in")
        for name, process in rows(best, denoiser, body, steps).items():
            process(noisy[:2])  # warm-up
            out, timing = common.file_to_file(files, Path(tmp) / "out", process)
            sets[name], speed[name] = out, timing.frames_per_s
            log(f"{name}: {timing.frames_per_s:,.0f} frames/s")
    return evaluate(gt, sets, body), speed, best


def section_marks(split: str) -> tuple[str, str]:
    """The markers of the split's section in the document (the test split's: the first)."""
    if split == "test":
        return SECTION_BEGIN, SECTION_END
    name = f"video_table_{split}"
    return f"<!-- {name}:begin (written by benchmarks/video_table.py) -->", f"<!-- {name}:end -->"


def markdown(result: dict, speed: dict, best: dict, header: str, split: str = "test") -> str:
    table = []
    gt = result["Ground truth"]
    table.append(
        ["Ground truth", "", "", f"(accel. {gt['accel']:.2f})", f"{gt['skate_cms']:.1f}", ""]
    )
    for name, r in result.items():
        if name == "Ground truth":
            continue
        fps = f"{speed[name]:,.0f}" if name in speed else ""
        table.append(
            [
                name,
                f"{r['mpjpe_cm']:.2f}",
                f"{r['v2v_cm']:.2f}",
                f"{r['accel_error']:.2f}",
                f"{r['skate_cms']:.1f}",
                fps,
            ]
        )
    head = ["", "MPJPE (cm)", "V2V (cm)", "accel. error (m/s²)", "foot skate (cm/s)", "frames/s"]
    filters = {
        k: v
        for k, v in result.items()
        if k not in ("Ground truth", "Noisy input", ROW_SLOW) and not k.startswith("`")
    }
    f_best = min(filters, key=lambda k: filters[k]["mpjpe_cm"])
    ours = result["`mdvae denoise` (video settings)"]
    f = filters[f_best]
    d_mpjpe = 100 * (ours["mpjpe_cm"] / f["mpjpe_cm"] - 1)
    d_accel = 100 * (ours["accel_error"] / f["accel_error"] - 1)
    ratio = (
        f"Against the best tuned filter ({f_best}): MPJPE {d_mpjpe:+.1f} %, acceleration "
        f"error {d_accel:+.1f} %."
    )
    title = "## Video-pipeline-like noise (`benchmarks/video_table.py`)"
    if split != "test":
        title += f", {split}"
    md = common.markdown_table(head, table)
    reading = (
        "What the numbers mean, and how the video settings were chosen: docs/model.md, "
        '"Video-like noise" and "Denoising video estimates".'
    )
    begin, end = section_marks(split)
    return f"{begin}\n{title}\n\n{header}\n\n{md}\n\n{ratio} {reading}\n{end}\n"


def main(argv: Sequence[str] | None = None) -> str:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=REPO / "data" / "corpus")
    p.add_argument("--max-clips", type=int, default=64)
    p.add_argument(
        "--split",
        default="test",
        choices=["test", "unseen_test"],
        help="the clips scored (the filters are tuned on val either way)",
    )
    p.add_argument("--val-clips", type=int, default=32)
    p.add_argument("--clip-frames", type=int, default=60, help="frames per clip (30 Hz)")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--denoiser", type=Path)
    p.add_argument("--out", type=Path)
    p.add_argument("--tune", action="store_true", help="also score the video row's candidates")
    p.add_argument("--quick", action="store_true", help="a few clips: checks that it runs")
    args = p.parse_args(argv)
    if args.quick:
        args.max_clips, args.val_clips, args.steps = 4, 4, 2
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    split = read_split(args.corpus / "split.json")
    frames = args.clip_frames
    test = common.load_clips(split[args.split], args.corpus, frames, max_clips=args.max_clips)
    val = common.load_clips(split["val"], args.corpus, frames, max_clips=args.val_clips)
    denoiser, _ = load_denoiser(args.denoiser)
    body = BodyModel(load_body_model(None))
    if args.tune:
        for name, r in tune_kind(val, denoiser, body, args.seed).items():
            if name != "Ground truth":
                print(
                    f"{name:24s} MPJPE {r['mpjpe_cm']:.2f}  V2V {r['v2v_cm']:.2f}  accel err "
                    f"{r['accel_error']:.2f}  skate {r['skate_cms']:.1f}"
                )
    result, speed, best = build(test, val, denoiser, body, args.steps, args.seed)
    row = INPUT_KINDS["video"]
    who = "held-out CMU subjects" if args.split == "test" else "kinds of motion training never saw"
    how = "" if args.split == "test" else f" --split {args.split}"
    how += "" if frames == 60 else f" --clip-frames {frames}"
    seconds = time.perf_counter() - start
    header = (
        f"{len(test)} {args.split} clips of {frames} frames (30 Hz, {who}) with `mdvae "
        f"add-noise --preset video` noise (seed {args.seed}); filters tuned on {len(val)} val "
        f"clips for the lowest MPJPE; shipped weights, built-in body; video settings: λ = "
        f"{row.lam:g}, offsets {row.offset_std:g} rad / {row.trans_offset_std:g} m, "
        f"{row.offset_terms} cosines, the result smoothed over {row.smooth_s:g} s as far as the "
        "input reads noisy. Foot skate: the ground truth's own is the first row. "
        f"Command: `python benchmarks/video_table.py --max-clips {args.max_clips} --val-clips "
        f"{args.val_clips}{how}` ({seconds:.0f} s, "
        f"{common.machine_description()['cpu']}, {args.threads} threads)."
    )
    md = markdown(result, speed, best, header, args.split)
    print(md)
    if args.out is not None and not args.quick:
        common.write_section(args.out, md, *section_marks(args.split))
    return md


if __name__ == "__main__":
    main()
