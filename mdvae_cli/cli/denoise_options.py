"""The options of ``mdvae denoise`` (kept apart from the command: its --help is long)."""

from __future__ import annotations

from pathlib import Path

import click

from mdvae_cli.cli.common import NON_NEGATIVE, POSITIVE, SEED, OutputPath
from mdvae_cli.cli.motion_input import missing_option
from mdvae_cli.help_figures import help_figures, span
from mdvae_cli.infer.fill_choices import DEFAULT_FILL

#: the benchmarks' figures the help quotes (benchmarks/help_figures.py)
_FIGURES = help_figures()
_D, _O, _F = _FIGURES["denoise"], _FIGURES["outliers"], _FIGURES["feet"]

#: click options, in --help order
OPTIONS = [
    click.option(
        "-o",
        "--out",
        required=True,
        type=OutputPath(),
        help="Output file (one input: .npz; a BVH take also as .bvh/.bvh.gz, an AMC take as "
        ".amc/.amc.gz, on its own skeleton) or folder (inputs mirrored below it, each in its own "
        "form).",
    ),
    click.option(
        "--denoiser",
        "denoiser_path",
        type=click.Path(path_type=Path),
        help="Denoiser checkpoint or fit-dataset folder (default: the shipped one).",
    ),
    click.option(
        "--optimize",
        "optimize_steps",
        type=click.IntRange(min=0),
        default=0,
        show_default=True,
        help="Optimisation mode: first fine-tune the inference networks on these files "
        "for N steps (the paper uses 50); 0 = regression mode, one forward pass.",
    ),
    click.option(
        "--per-file",
        is_flag=True,
        help="With --optimize: adapt once per file instead of once to the whole set.",
    ),
    click.option(
        "--lr",
        type=POSITIVE,
        default=None,
        help="With --optimize: its learning rate (> 0) [default: 3e-4].",
    ),
    click.option(
        "--seed", type=SEED, default=0, show_default=True, help="With --optimize: its random seed."
    ),
    click.option(
        "--refine",
        "refine_steps",
        type=click.IntRange(min=0),
        default=0,
        show_default=True,
        help="Then refine every window's latents for N gradient steps on its own ELBO, scoring "
        "the file's noisy joint rotations with a noise level estimated per joint (50 is a good "
        f"value: markedly cleaner, about {_D['refine_slowdown']:g}x slower than one pass with "
        "the offset); 0 = off.",
    ),
    click.option(
        "--refine-lr",
        type=POSITIVE,
        default=0.1,
        show_default=True,
        help="Step size of --refine (> 0).",
    ),
    click.option(
        "--refine-offset",
        type=NON_NEGATIVE,
        default=None,
        help="The scale (rad) each joint's slow rotation offset (--offset, --refine) starts from "
        "in every window, then estimated from the file. 0 = no offset. [default: 0.03, or the "
        "input kind's setting]",
    ),
    click.option(
        "--trans-offset",
        type=NON_NEGATIVE,
        default=None,
        help="The scale (m) the root translation's slow offset (--offset) starts from in every "
        "window: it keeps the file's path, from which the decoded one drifts by ~4 cm. 0 = no "
        "translation offset. (--refine fits the translation itself.) [default: 0.03, or the "
        "input kind's setting]",
    ),
    click.option(
        "--smooth",
        "smooth",
        type=NON_NEGATIVE,
        default=None,
        help="The standard deviation (seconds) of a Gaussian over the cleaned motion, after the "
        "foot lock, in full where the input reads noisy and not at all where it reads clean (a "
        "pipeline's output that it smoothed itself comes back as without it). The networks were "
        "fitted to mocap noise, and what a video tracker's jitter leaves in their output is "
        "smoothed away: on video-like noise the acceleration error falls by a fifth to two "
        "fifths at the same accuracy. 0 = none. Not with --no-offset. [default: 0.05 for "
        "video inputs, 0 for mocap]",
    ),
    click.option(
        "--offset/--no-offset",
        default=True,
        show_default=True,
        help="After the forward pass, fit a slow rotation offset per joint, and one for the root "
        "translation, to the file in closed form (no gradient steps): it follows slow motion the "
        "learned prior cannot express, so clean parts of a take come back almost unchanged, the "
        "body keeps the file's path, and the result is more accurate than a tuned filter, at "
        f"~{_D['offset_time']:g}x the time. --no-offset is the paper's plain regression mode. "
        "Part of --refine already.",
    ),
    click.option(
        "--loop/--no-loop",
        default=None,
        help="Denoise every take as a cycle (a game loop whose last frame leads into its first): "
        "its ends get context from each other and the seam stays continuous when it plays on "
        "repeat. Default: a take whose last pose is within two frame steps of its first is "
        "treated as a loop, and said so; --no-loop never (--loop on a take whose ends do not meet "
        "says so too).",
    ),
    click.option(
        "--blend/--no-blend",
        default=None,
        help="Put back what of the input's difference from the denoised motion its own noise "
        "does not explain, joint by joint and second by second: a clean take (or a clean "
        "stretch, or a joint that is clean) comes back as it came, a noisy one cleaned, and a "
        "spike in the input (one frame jumping away and back) is filled as a short hole: from "
        "the take's own frames beside it in a clean take, from the denoised frame in a noisy "
        "one. The share kept is in the summary and in --json "
        '("input_share"). On by default, except with --outliers, whose heavy-tailed noise '
        "model already weighs the spikes (such takes come out more accurate without the blend). "
        "Not with --no-offset, which is the paper's regression mode untouched.",
    ),
    click.option(
        "--guard/--no-guard",
        default=False,
        show_default=True,
        help="The last resort: where a denoised stretch moved further from the input than the "
        "input's own noise explains, use the input smoothed instead, and say so once per take "
        '(summary line, --json "fallbacks" and "fallback_share"). Off by default: --blend '
        "already leans on the input there, and costs no accuracy on unseen kinds of motion. "
        "Not with --no-offset.",
    ),
    click.option(
        "--outliers",
        is_flag=True,
        help="Model the noise as heavy-tailed (Student-t, 10 degrees of freedom, = --lam 10) per "
        "frame and joint, so spikes (a swapped marker, a solver flip) are down-weighted where they "
        "happen instead of raising the whole joint's noise level: with --refine, "
        f"{span(_O['spike_gain_pct'], ' %')} lower error on takes with spikes, "
        f"{span(_O['even_cost_pct'], ' %')} higher on evenly noisy ones (benchmarks/outliers.py); "
        "without --refine (the video setting) smoother, but worse on spiky mocap takes.",
    ),
    click.option(
        "--lam",
        type=NON_NEGATIVE,
        default=None,
        help="The paper's lambda: degrees of freedom of the Student-t noise per frame and joint "
        "that the offset and --refine assume (smaller: heavier tails, flips and spikes count "
        "less); 0 = Gaussian. [default: 0 for mocap files; the video setting for video-pipeline "
        "outputs (docs/model.md)]",
    ),
    click.option(
        "--input-kind",
        type=click.Choice(["auto", "mocap", "video"]),
        default="auto",
        show_default=True,
        help="Which settings row to start from: 'video' for a video pipeline's estimates (chosen "
        "automatically for their files), 'mocap' otherwise; options override either.",
    ),
    click.option(
        "--mirror",
        is_flag=True,
        help="Also denoise each file's left-right mirror image and average the two results (the "
        "learned prior is not exactly mirror-symmetric): with --refine 50, "
        f"{span(_D['mirror_refine_gain_pct'], ' %')} lower error on the test walks at "
        f"{_D['mirror_time']:g}x the time; less with the default's offset, which already absorbs "
        "much of what the two images disagree on.",
    ),
    click.option(
        "--feet",
        type=click.Choice(["lock", "off"]),
        default="lock",
        show_default=True,
        help="lock: where a foot is clearly planted (a foot joint low and slow; the rule "
        "widens with the input's noise), hold it still by swinging its leg about the hip, the "
        "knee keeping its bend; frames away from contacts are left as denoised, and a clean take "
        "keeps its own feet. On noisy clips (0.10-0.20 rad) foot skate falls from "
        f"{span(_F['test']['skate_off'])} times the truth's to {span(_F['test']['skate_lock'])} "
        f"times on the test walks ({span(_F['unseen_test']['skate_off'])} to "
        f"{span(_F['unseen_test']['skate_lock'])} on unseen kinds of motion), the vertex error by "
        f"{span(_F['test']['v2v_gain_pct'], ' %')} ({span(_F['unseen_test']['v2v_gain_pct'], ' %')}"
        f"), for ~{span(_F['ms_per_frame'])} ms a frame on a long take (docs/benchmarks.md, "
        '"Feet and floor"). off: the feet as denoised.',
    ),
    click.option(
        "--fill",
        type=click.Choice(["on", "off", DEFAULT_FILL]),
        default="on",
        show_default=True,
        help="on: fill the holes of a take (frames and joints that are missing: NaN in an npz, "
        "frames a video track skips, what --missing names in a BVH/AMC take) by the default "
        f"way, {DEFAULT_FILL}: a cubic curve per joint from the frames beside the hole (the "
        "take's own on a clean take, the cleaned ones on a noisy one), or over a hole of every "
        "joint of 0.3 s or more a stretch of the take whose frames either side match the "
        "hole's, where one does (a --denoiser fitted with `fit-dataset --holes` reads the holes "
        "and writes its own frames in a noisy take's); the summary and --json "
        'say how many ("filled_frames", "filled_joints"). off: leave them as they came (an npz '
        "gets its NaN back, a take its own frames).",
    ),
    missing_option,
    click.option(
        "--floor",
        is_flag=True,
        help="Put each input on the floor first: the ground under its soles moved to z = 0 (as "
        "mdvae import --floor flat does). Off by default: heights stay as the file has them (a "
        "video pipeline's file as the pipeline wrote it, the same as after mdvae import).",
    ),
    click.option(
        "--mesh-dir",
        type=click.Path(path_type=Path),
        help="Also write the cleaned mesh sequence here (one input: into the folder itself; "
        "several: a subfolder per file).",
    ),
    click.option(
        "--mesh-format",
        type=click.Choice(["obj", "ply"]),
        default=None,
        help="Mesh file format for --mesh-dir [default: ply].",
    ),
    click.option(
        "--view",
        "view_dir",
        type=click.Path(path_type=Path),
        help="Also write a before/after page per file here (<name>.html, folders mirrored): the "
        "input and the cleaned motion playing side by side in any browser (see mdvae view).",
    ),
    click.option(
        "--window",
        type=click.IntRange(min=8),
        default=60,
        show_default=True,
        help="Frames per window at 30 Hz (as trained).",
    ),
    click.option(
        "--overlap",
        type=click.IntRange(min=1),
        default=15,
        show_default=True,
        help="Frames shared by consecutive windows, cross-faded.",
    ),
    click.option(
        "--asf",
        type=click.Path(path_type=Path, dir_okay=False),
        help="Skeleton for .amc inputs (default: <subject>.asf or the only .asf next to each).",
    ),
    click.option(
        "--joint-map",
        "joint_map_file",
        type=click.Path(path_type=Path, dir_okay=False),
        help="For BVH/AMC takes whose joint names are not recognised: a JSON file naming them, "
        'e.g. {"pelvis": "Hips", "left_hip": "LeftUpLeg", "head": "Head"} (SMPL joint -> yours).',
    ),
]


def fill_setting(option: str) -> str:
    """``--fill``'s value as ``DenoiseSettings.fill`` ("on": the default fill)."""
    return DEFAULT_FILL if option == "on" else option


def fill_words(done: list[dict]) -> str:
    """What the summary line says of the holes and the filled spikes (nothing when there were
    none)."""
    from mdvae_cli.run.denoise_files import fill_totals

    total = fill_totals(done)
    spikes = (f"; filled {total['spike_frames']} frame(s) with a spike (a joint away and back)"
              if total["spike_frames"] else "")  # fmt: skip
    if total["filled_frames"]:
        return (f"; filled {total['filled_frames']} frame(s) with missing joints "
                f"({total['filled_joints']} joint entries){spikes}")  # fmt: skip
    if total["unfilled_frames"]:
        return (f"; {total['unfilled_frames']} frame(s) with holes left as they came "
                f"(--fill off){spikes}")  # fmt: skip
    return spikes


def denoise_options(command):
    """Apply every option of :data:`OPTIONS` to the command function (as stacked decorators
    would, first listed first in --help)."""
    for option in reversed(OPTIONS):
        command = option(command)
    return command
