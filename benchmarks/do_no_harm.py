"""Do no harm: what ``mdvae denoise`` changes on clean and lightly noisy motion, at every sigma.

Three parts, each a markdown table (``--write`` puts them into ``docs/benchmarks.md``):

* **sigma sweep** on the corpus's ``test`` and ``unseen_test`` clips (60 frames at 30 Hz):
  Pose-NDF noise sigma = 0, 0.02, 0.05, 0.10, 0.15, 0.20 rad; V2V (cm) of the noisy input, of the
  best filter tuned on those very clips at that sigma (Gaussian and Savitzky-Golay grids), of
  the default and of the settings it is made of; acceleration (m/s^2) and foot skate (cm/s)
  beside the truth's;
* **high rate**: clean 120 Hz studio takes (the shared real BVH at 120 Hz) with and without
  noise, denoised at their own rate and at 30 Hz: V2V against the truth at that rate, and the
  clean takes' acceleration against the input's;
* **real files**: the shared real BVH takes before and after the default: mean change (V2V
  between input and output, cm), knee-flexion peak change (deg), acceleration and foot skate
  in -> out, the share of the input kept as it came and of frames the guard replaced;
* **clean and spiky takes** (``clean_long``): 150-frame clips of both splits, clean and with
  ``benchmarks/outliers.py``'s spikes (clean, or with Pose-NDF noise of sigma 0.05): V2V (cm)
  of the input and of the default, and how many joint-frames (the root and 21 body joints)
  each turns by more than 20 degrees from the truth.

    python benchmarks/do_no_harm.py [--clips 40] [--write]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

try:
    from benchmarks import common, outliers
except ModuleNotFoundError:  # run as a file
    import common  # type: ignore[no-redef]
    import outliers  # type: ignore[no-redef]

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.export import DEFAULT_CHUNK_FRAMES, pose_motion_chunks
from mdvae_cli.filters import gaussian_filter_motion, savgol_filter_motion
from mdvae_cli.foot_metrics import contact_slide_speeds
from mdvae_cli.formats.registry import ReadOptions, read
from mdvae_cli.geometry.rotations_np import rotvec_to_quat
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig
from mdvae_cli.infer.input_kinds import refine_config
from mdvae_cli.metrics import joint_acceleration, v2v
from mdvae_cli.motion.contacts import FOOT_JOINTS, contacts_of_feet
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise, file_rng
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.train.corpus import select_files

REPO = Path(__file__).resolve().parents[1]
SIGMAS = (0.0, 0.02, 0.05, 0.10, 0.15, 0.20)
GAUSSIAN_GRID = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
SAVGOL_GRID = ((5, 1), (7, 1), (9, 1), (11, 1), (9, 2), (13, 2))
#: the real takes a studio would hand over clean (video estimates are noisy by nature)
CLEAN_TAKES = (
    "xyz_end_joints/AV_8Walk_Meredith_HVHA_Rep1.bvh.gz",
    "bone_axis_offsets/jesse_dance.bvh.gz",
    "xsens_style/bvh_test2.bvh.gz",
    "fingers_mixed_orders/bvh_test3.bvh.gz",
    "asf_names_no_endsite/motorcycle.bvh.gz",
    "biovision_classic/test_mocapbank.bvh.gz",
    "zup_mixed_orders/bvh_test1.bvh.gz",
    "makehuman/zombieWalk1.bvh.gz",
)
VIDEO_TAKES = ("video_zup_mm/cxk.bvh.gz", "smpl_fbx_rig/dance2.bvh.gz")
HIGH_RATE = CLEAN_TAKES[:5]
KNEES = (3, 4)  # left and right knee in pose_body
#: the clean and spiky takes: clip length, and the scenarios (clean first)
LONG_FRAMES = 150
SPIKY = (
    outliers.Scenario(0.0),
    outliers.Scenario(0.0, 0.01, 1.0),
    outliers.Scenario(0.0, 0.02, 0.3),
    outliers.Scenario(0.05, 0.02, 1.0),
    outliers.Scenario(0.05, 0.05, 0.5),
)
#: a joint-frame turned by more than this from the truth counts as moved (degrees)
MOVED_DEG = 20.0


def methods(denoiser, body) -> dict[str, Callable[[list[Motion]], list[Motion]]]:
    """The rows: the default and the settings it is made of (mocap settings, as for BVH/npz)."""
    cfg, _ = refine_config("mocap", steps=0)

    def run(blend: bool, guard: bool, feet: bool):
        lock = FootLockConfig() if feet else None
        return lambda ms: denoise_motions(
            ms, denoiser, body, refine=cfg, blend=blend, guard=guard, feet=lock
        )

    return {
        "`mdvae denoise` (default: blend, feet lock)": run(True, False, True),
        "`--feet off`": run(True, False, False),
        "`--no-blend --feet off` (the model + offset alone)": run(False, False, False),
        "`--no-blend --guard` (the previous default)": run(False, True, True),
    }


def tuned_filter(gt, noisy, body) -> tuple[str, float]:
    """The best filter on these very clips: (its name, V2V cm)."""
    cands = {
        f"Gaussian {s:g}": [gaussian_filter_motion(m, s) for m in noisy] for s in GAUSSIAN_GRID
    }
    for w, p in SAVGOL_GRID:
        cands[f"Savitzky-Golay {w}/{p}"] = [savgol_filter_motion(m, w, p) for m in noisy]
    scores = {k: r.v2v_cm for k, r in common.evaluate_clips(gt, cands, body).items()}
    best = min(scores, key=scores.get)
    return best, scores[best]


def sweep(split: str, n_clips: int, denoiser, body, log) -> str:
    corpus = REPO / "data" / "corpus"
    files = select_files([corpus], corpus / "split.json", split)
    clips = common.load_clips(files, corpus, 60, max_clips=n_clips)
    gt = [c.motion for c in clips]
    rows = methods(denoiser, body)
    table: dict[str, list[str]] = {"noisy input": [], "best filter tuned on these clips": []}
    table.update({k: [] for k in rows})
    extra: dict[str, list[str]] = {k: [] for k in ("truth", *rows)}
    for sigma in SIGMAS:
        noisy = common.add_noise(clips, sigma, 0) if sigma > 0 else list(gt)
        preds = {k: fn(noisy) for k, fn in rows.items()}
        res = common.evaluate_clips(gt, {"noisy input": noisy, **preds}, body)
        name, score = tuned_filter(gt, noisy, body) if sigma > 0 else ("the input", 0.0)
        table["noisy input"].append(f"{res['noisy input'].v2v_cm:.2f}")
        table["best filter tuned on these clips"].append(f"{score:.2f} ({name})")
        for k in rows:
            table[k].append(f"{res[k].v2v_cm:.2f}")
            extra[k].append(f"{res[k].accel_pred:.2f} / {res[k].foot_skate_pred:.1f}")
        first = res["noisy input"]
        extra["truth"].append(f"{first.accel_gt:.2f} / {first.foot_skate_gt:.1f}")
        log(f"{split} sigma {sigma:g}: " + ", ".join(f"{k[:24]} {v[-1]}" for k, v in table.items()))
    head = ["V2V cm, sigma (rad) =", *(f"{s:g}" for s in SIGMAS)]
    out = [f"**{split}** ({len(clips)} clips of 60 frames at 30 Hz)\n"]
    out.append(common.markdown_table(head, [[k, *v] for k, v in table.items()]))
    head = ["acceleration m/s² / foot skate cm/s, sigma =", *(f"{s:g}" for s in SIGMAS)]
    out.append("\n" + common.markdown_table(head, [[k, *v] for k, v in extra.items()]))
    return "\n".join(out)


def posed(motion: Motion, body: BodyModel) -> tuple[torch.Tensor, torch.Tensor]:
    """Joints (T, 22, 3) and vertices (T, V, 3) of a motion, float64."""
    chunks = list(pose_motion_chunks(motion, body, DEFAULT_CHUNK_FRAMES, vertices=True))
    joints = torch.cat([o.joints for _, o in chunks]).double()
    return joints, torch.cat([o.vertices for _, o in chunks]).double()


def knee_peak_change(a: Motion, b: Motion) -> float:
    """The largest change of a knee's flexion peak (99th percentile of its angle), degrees."""
    out = 0.0
    for k in KNEES:
        pa = np.percentile(np.linalg.norm(a.pose_body[:, k], axis=-1), 99)
        pb = np.percentile(np.linalg.norm(b.pose_body[:, k], axis=-1), 99)
        out = max(out, abs(float(np.degrees(pb - pa))))
    return out


def skate(joints: torch.Tensor, fps: float) -> float:
    """Mean slide speed of the foot joints where the motion's own contacts hold them, cm/s."""
    j = joints.numpy()
    speeds = contact_slide_speeds(j, contacts_of_feet(j[:, list(FOOT_JOINTS)], fps), fps)
    return 100.0 * float(speeds.mean()) if speeds.size else float("nan")


def change_of(src: Motion, out: Motion, body: BodyModel) -> dict[str, float]:
    j0, v0 = posed(src, body)
    j1, v1 = posed(out, body)
    foot = skate(j0, src.fps), skate(j1, src.fps)
    return {
        "change": 100.0 * float(v2v(v1, v0).mean()),
        "knee": knee_peak_change(src, out),
        "acc_in": float(joint_acceleration(j0, src.fps).mean()),
        "acc_out": float(joint_acceleration(j1, src.fps).mean()),
        "skate_in": foot[0],
        "skate_out": foot[1],
    }


def read_take(rel: str, body_data) -> Motion:
    path = REPO.parent / "shared" / "data" / "real" / "bvh" / rel
    return read(path, ReadOptions(body=body_data)).single()


def real_files(denoiser, body, log) -> str:
    cfg, _ = refine_config("mocap", steps=0)
    rows = []
    for rel in (*CLEAN_TAKES, *VIDEO_TAKES):
        src = read_take(rel, body.data)
        reports, falls = [], []
        out = denoise_motions(
            [src], denoiser, body, refine=cfg, blend=True, feet=FootLockConfig(),
            on_blend=lambda i, r, got=reports: got.append(r),
            on_fallback=lambda i, a, b, got=falls: got.append(b - a),
        )[0]  # fmt: skip
        c = change_of(src, out, body)
        kind = "video estimate" if rel in VIDEO_TAKES else "clean"
        rows.append([
            f"`{Path(rel).name}` ({kind}, {src.fps:.0f} Hz, {src.num_frames} frames)",
            f"{c['change']:.2f}", f"{c['knee']:.1f}",
            f"{c['acc_in']:.2f} → {c['acc_out']:.2f}",
            f"{c['skate_in']:.1f} → {c['skate_out']:.1f}",
            f"{100 * reports[0].input_share:.0f} %", "0 %" if not falls else "> 0",
        ])  # fmt: skip
        log(f"real {rel}: {rows[-1][1:]}")
    head = ["take", "mean change cm", "knee peak change °", "accel. m/s² in → out",
            "foot skate cm/s in → out", "input kept", "guard"]  # fmt: skip
    return common.markdown_table(head, rows)


def high_rate(denoiser, body, log) -> str:
    cfg, _ = refine_config("mocap", steps=0)
    run = lambda ms: denoise_motions(ms, denoiser, body, refine=cfg, blend=True)  # noqa: E731
    rows = []
    for rel in HIGH_RATE:
        truth = read_take(rel, body.data)
        noisy = add_pose_noise(truth, 0.10, file_rng(0, rel))
        own = run([noisy])[0]
        truth30, noisy30 = resample_motion(truth, 30.0), resample_motion(noisy, 30.0)
        at30 = run([noisy30])[0]
        clean = run([truth])[0]
        v_own = 100 * float(v2v(posed(own, body)[1], posed(truth, body)[1]).mean())
        v_30 = 100 * float(v2v(posed(at30, body)[1], posed(truth30, body)[1]).mean())
        acc_in = float(joint_acceleration(posed(truth, body)[0], truth.fps).mean())
        acc_out = float(joint_acceleration(posed(clean, body)[0], truth.fps).mean())
        rows.append([
            f"`{Path(rel).name}` ({truth.fps:.0f} Hz)", f"{v_own:.2f}", f"{v_30:.2f}",
            f"{acc_in:.2f} → {acc_out:.2f} ({100 * (acc_out / acc_in - 1):+.0f} %)",
        ])  # fmt: skip
        log(f"high rate {rel}: {rows[-1][1:]}")
    head = ["take", "σ 0.10: V2V cm at its own rate", "at 30 Hz",
            "clean: acceleration m/s² in → out"]  # fmt: skip
    return common.markdown_table(head, rows)


def turned_degrees(a: Motion, b: Motion) -> np.ndarray:
    """The angle between two motions' rotations of the root and 21 body joints, per frame and
    joint, degrees.  -> (T, 22)"""
    qa, qb = (
        rotvec_to_quat(np.concatenate([m.root_orient[:, None], m.pose_body[:, :21]], axis=1))
        for m in (a, b)
    )
    dot = np.clip(np.abs((qa * qb).sum(-1)), 0.0, 1.0)
    return np.degrees(2.0 * np.arccos(dot))


def clean_and_spiky(split: str, n_clips: int, denoiser, body, log) -> str:
    """The default on clean 150-frame clips and on the same clips with spikes."""
    corpus = REPO / "data" / "corpus"
    files = select_files([corpus], corpus / "split.json", split)
    clips = common.load_clips(files, corpus, LONG_FRAMES, max_clips=n_clips)
    gt = [c.motion for c in clips]
    default = next(iter(methods(denoiser, body).values()))
    rows = []
    for sc in SPIKY:
        noisy = outliers.noisy_clips(clips, sc, 0) if sc.spike_frac or sc.sigma else list(gt)
        out = default(noisy)
        res = common.evaluate_clips(gt, {"in": noisy, "out": out}, body)
        moved = [
            sum(int((turned_degrees(g, m) > MOVED_DEG).sum()) for g, m in zip(gt, ms, strict=True))
            for ms in (noisy, out)
        ]
        label = "clean" if sc == SPIKY[0] else sc.label
        rows.append([label, f"{res['in'].v2v_cm:.3f}", f"{res['out'].v2v_cm:.3f}",
                     f"{moved[0]} → {moved[1]}"])  # fmt: skip
        log(f"{split} {label}: {rows[-1][1:]}")
    head = ["input", "V2V cm, input", "the default",
            f"joint-frames > {MOVED_DEG:g}° from the truth, input → default"]  # fmt: skip
    return (f"**{split}, clean and spiky** ({len(clips)} clips of {LONG_FRAMES} frames)\n\n"
            + common.markdown_table(head, rows))  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clips", type=int, default=40, help="clips per split (spread evenly)")
    ap.add_argument("--splits", default="test,unseen_test")
    ap.add_argument("--parts", default="sweep,high_rate,real,clean_long", help="which tables")
    ap.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    ap.add_argument("--denoiser", help="denoiser checkpoint or folder (default: the shipped one)")
    args = ap.parse_args(argv)
    if args.write and args.denoiser:
        ap.error("--write documents the shipped weights: leave out --denoiser")
    denoiser, body, log = common.shipped_models_and_log(args.denoiser)

    parts = args.parts.split(",")
    text = []
    if "sweep" in parts:
        for split in args.splits.split(","):
            text.append(sweep(split, args.clips, denoiser, body, log))
    if "high_rate" in parts:
        text.append("**High rate** (real 120 Hz studio takes)\n\n" + high_rate(denoiser, body, log))
    if "real" in parts:
        text.append(
            "**Real files** (the default, before → after)\n\n" + real_files(denoiser, body, log)
        )
    if "clean_long" in parts:
        for split in args.splits.split(","):
            text.append(clean_and_spiky(split, args.clips, denoiser, body, log))
    section = (
        "<!-- do-no-harm:begin -->\n## Do no harm\n\n"
        + "\n\n".join(text)
        + f"\n\n({common.cpu_model()}; `python benchmarks/do_no_harm.py --clips {args.clips}`)"
        + "\n<!-- do-no-harm:end -->"  # without it, --write appended the section again
    )
    print(section)
    if args.write:
        common.write_section(REPO / "docs" / "benchmarks.md", section,
                             "<!-- do-no-harm:begin -->", "<!-- do-no-harm:end -->")  # fmt: skip


if __name__ == "__main__":
    main()
