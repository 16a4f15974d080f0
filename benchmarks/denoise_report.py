"""The denoising table as markdown and as Figure 1 (``benchmarks/denoise_table.py``)."""

from __future__ import annotations

import math
from pathlib import Path

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/denoise_table.py
    import common  # type: ignore[no-redef]

try:
    from benchmarks.denoise_rows import (
        ROW_GT,
        ROW_OBS,
        FilterTuning,
        TableResult,
        TableSettings,
        section_markers,
    )
except ModuleNotFoundError:  # run as a file
    from denoise_rows import (  # type: ignore[no-redef]
        ROW_GT,
        ROW_OBS,
        FilterTuning,
        TableResult,
        TableSettings,
        section_markers,
    )


# --------------------------------------------------------------------------------------------
# rendering


def table_columns(settings: TableSettings) -> list[str]:
    """Header cells of the table, in order."""
    ref = f"{settings.reference_sigma:.2f}"
    return [
        "Method",
        "Parameters",
        "s/frame ↓",
        "frames/s ↑",
        "1 clip, warm (ms)",
        *(f"V2V σ={s:.2f} (cm) ↓" for s in settings.sigmas),
        *(f"Accel σ={s:.2f} (m/s²)" for s in settings.sigmas),
        f"Foot skate σ={ref} (cm/s)",
        f"Penetration σ={ref} (cm)",
        f"Float σ={ref} (cm)",
        f"absolute V2V σ={ref} (cm)",
        f"V2V / V2V(obs) σ={ref}",
        f"improvement over best filter σ={' / '.join(f'{x:.2f}' for x in settings.sigmas)}",
    ]


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def table_rows(result: TableResult) -> list[list[str]]:
    """The table's body cells, one list per row (same order as :func:`table_columns`)."""
    s = result.settings
    ref = s.reference_sigma
    obs = result.row(ROW_OBS).v2v(ref)
    best = result.best_filter
    out = []
    for r in result.rows:
        gt_row = r.name == ROW_GT
        accel = [r.results[x].accel_pred for x in s.sigmas]
        absolute = None if gt_row else r.results[ref].v2v_abs_cm
        if gt_row:
            v2v, ratio, gain = [None] * len(s.sigmas), "-", "-"
        else:
            v2v = [r.v2v(x) for x in s.sigmas]
            ratio = _num(r.v2v(ref) / obs if obs > 0 else None, ".3f")
            gains = (100 * (1 - r.v2v(x) / best.v2v(x)) for x in s.sigmas)
            gain = "best filter" if r is best else " / ".join(f"{g:+.1f} %" for g in gains)
        out.append(
            [
                r.name,
                r.params or "-",
                _num(r.speed.s_per_frame if r.speed else None, ".3g"),
                _num(r.speed.frames_per_s if r.speed else None, ",.0f"),
                _num(None if r.one_clip_s is None else 1000 * r.one_clip_s, ".3g"),
                *(_num(v, ".2f") for v in v2v),
                *(_num(a, ".2f") for a in accel),
                _num(r.results[ref].foot_skate_pred, ".2f"),
                _num(r.results[ref].penetration_pred, ".3f"),
                _num(r.results[ref].float_pred, ".3f"),
                _num(absolute, ".2f"),
                ratio,
                gain,
            ]
        )
    return out


def tuning_markdown(t: FilterTuning) -> str:
    """The val grid as two small tables (V2V in cm)."""
    gauss = common.markdown_table(
        ["Gaussian σ (frames)", *(f"{k:g}" for k in t.gaussian_scores)],
        [["V2V (cm)", *(f"{v:.2f}" for v in t.gaussian_scores.values())]],
    )
    windows = sorted({w for w, _ in t.savgol_scores})
    orders = sorted({p for _, p in t.savgol_scores})
    sg = common.markdown_table(
        ["S-G window \\ order", *(str(p) for p in orders)],
        [[str(w), *(_num(t.savgol_scores.get((w, p)), ".2f") for p in orders)] for w in windows],
    )
    return gauss + "\n\n" + sg


def report_markdown(
    result: TableResult,
    machine: dict[str, str],
    context: dict[str, str],
    plot_link: str | None,
) -> str:
    """The whole section for docs/benchmarks.md (between the section markers)."""
    s, t = result.settings, result.tuning
    ref = f"{s.reference_sigma:.2f}"
    gw, (sw, sp) = t.gaussian_sigma, t.savgol
    begin, end = section_markers(result.split)
    title = {
        "test": "## Denoising noisy mocap (paper Table 1 and Figure 1)",
        "unseen_test": "## Denoising kinds of motion the prior never saw (unseen_test split)",
    }.get(result.split, f"## Denoising noisy mocap ({result.split} split)")
    lines = [
        begin,
        title,
        "",
        f"{result.num_clips} clips of {result.clip_frames} frames (30 Hz) from the "
        f"{result.split} split, "
        f"Pose-NDF noise σ = {', '.join(f'{x:.2f}' for x in s.sigmas)} rad on the body joints "
        f"(seed {s.seed}). V2V is root-relative (cm), as in the paper; the absolute V2V "
        "keeps the root translation in (the noise leaves it clean: a method that moves it "
        "pays here). The acceleration is the mean joint "
        "acceleration (m/s²; the closer to the ground truth the better). Foot skate, penetration "
        "and float are `mdvae eval`'s, on the ground truth's contacts and floor (the ground truth "
        "row gives its own values; docs/benchmarks.md, 'Feet and floor'). Speed is measured file "
        f"to file at σ = {ref}: loading, denoising and saving all clips in one run; "
        "'1 clip, warm' is one clip processed alone after a warm-up (median). The last two "
        f"columns compare V2V with the observations' (at σ = {ref}) and with the better filter's "
        f"(the one tuned at σ = {ref}; at every σ; positive = lower error).",
        "",
        common.markdown_table(table_columns(s), table_rows(result)),
        "",
        f"Filters tuned on {t.clips} {result.tuned_on} clips at σ = {t.noise_sigma:.2f} "
        "(lowest V2V; "
        f"observations {t.observations_v2v:.2f} cm): Gaussian σ = {gw:g} frames, "
        f"Savitzky-Golay window {sw} / order {sp}.",
        "",
        f"<details><summary>Filter grid on the {result.tuned_on} clips (V2V, cm)</summary>",
        "",
        tuning_markdown(t),
        "",
        "</details>",
        "",
    ]
    if plot_link:
        lines += [f"![V2V versus speed at σ = {ref}]({plot_link})", ""]
    curve = ", ".join(
        f"{p.steps}: {p.v2v_cm:.2f} cm @ {p.s_per_frame:.3g} s/frame"
        for p in result.curve
        if p.steps is not None
    )
    lines += [f"Optimisation steps (σ = {ref}): {curve}.", "", "Setup:", ""]
    lines += [f"- {k}: {v}" for k, v in context.items()]
    lines += [f"- {k}: {v}" for k, v in machine.items()]
    lines += ["", end]
    return "\n".join(lines) + "\n"


def plot_speed_accuracy(result: TableResult, path: Path, fps: float = 30.0) -> bool:
    """Figure 1: V2V versus s/frame (log x) at the reference sigma. False without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    ref = result.settings.reference_sigma
    obs = result.row(ROW_OBS).v2v(ref)
    ours = [p for p in result.curve if p.steps is not None]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=150)
    ax.plot([p.s_per_frame for p in ours], [p.v2v_cm for p in ours], "o-", label="Motion-DVAE")
    for p in ours:
        ax.annotate(str(p.steps), (p.s_per_frame, p.v2v_cm), textcoords="offset points",
                    xytext=(4, 4), fontsize=8)  # fmt: skip
    for p, marker in zip([p for p in result.curve if p.steps is None], "sD^v<>P", strict=False):
        ax.plot([p.s_per_frame], [p.v2v_cm], marker, label=p.label)
    ax.axhline(obs, color="grey", ls="--", lw=1, label=f"observations ({obs:.1f} cm)")
    ax.axhline(obs * (2 / 3), color="tab:red", ls=":", lw=1, label="-33 % error")
    ax.axvline(10 / fps, color="tab:purple", ls=":", lw=1, label="10x slower than real time")
    ax.set_xscale("log")
    ax.set_xlabel("speed (s/frame, file to file, log scale)")
    ax.set_ylabel("V2V (cm)")
    ax.set_title(f"Accuracy versus speed, σ = {ref:.2f}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return True
