"""The refined targets of a ``fit-dataset`` run's distillation, kept in its folder.

Refining every noisy training window for 50 steps takes a good part of an hour on a CPU, so
the targets are saved in the run folder (``distill_targets.npz``): a resumed run, or a new run
from the same networks, reads them back instead of making them again. A run stopped while
making them (a Ctrl-C or SIGTERM the command caught) keeps the windows refined so far, and so
does a run killed outright up to its last save (every ``KEEP_SECONDS``); ``--resume`` refines
the rest. Each window's refinement depends on that window alone, so targets made in parts are
those made at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from mdvae_cli.infer.window_groups import WindowGroup
from mdvae_cli.model.checkpoint import load_checkpoint, save_checkpoint
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.train.distill import Targets, refine_targets
from mdvae_cli.train.distributed import parameter_digest
from mdvae_cli.workers import worker_count

TARGETS_FILE = "distill_targets.npz"
#: while targets are being made, those made so far are saved this often (seconds)
KEEP_SECONDS = 300.0
NAMES = ("z", "x0", "z_logvar")


def prefixes_of(groups: list[WindowGroup]) -> list[str]:
    """The tensor-name prefix of each group in the file: one group's tensors are stored
    unprefixed (as before groups), more groups' as ``g<i>/...``."""
    return [""] if len(groups) == 1 else [f"g{i}/" for i in range(len(groups))]


def file_key(groups: list[WindowGroup], refine_steps: int) -> dict:
    """What targets in a file must have been made for: these windows, this many steps."""
    sizes = [len(g) for g in groups]
    return {"windows": sizes[0] if len(sizes) == 1 else sizes, "refine_steps": refine_steps}


def stored_targets(
    path: Path, groups: list[WindowGroup], refine_steps: int, digest: str, any_networks: bool
) -> list[Targets | None] | None:
    """The targets in ``path`` per group, made for these windows and steps from networks with
    parameter ``digest`` (``any_networks``: from whichever networks, for a run part way through
    distillation), each covering the group's first windows or all of them; None for a group
    none were made for yet. None when the file is missing or made for something else."""
    if not path.exists():
        return None
    tensors, meta = load_checkpoint(path)
    if any(meta.get(k) != v for k, v in file_key(groups, refine_steps).items()):
        return None
    if not (any_networks or meta.get("networks") == digest):
        return None
    out: list[Targets | None] = []
    for p, g in zip(prefixes_of(groups), groups, strict=True):
        have = [p + n in tensors for n in NAMES]
        if not all(have):
            if any(have):
                return None
            out.append(None)
            continue
        t = Targets(*(tensors[p + n] for n in NAMES))
        if len(t) > len(g):
            return None
        out.append(t)
    return out


def save_targets(
    path: Path, groups: list[WindowGroup], refine_steps: int, digest: str,
    targets: list[Targets | None],
) -> None:  # fmt: skip
    """Write the targets made so far (a group's first windows, or None for none yet)."""
    tensors = {
        p + n: getattr(t, n)
        for p, t in zip(prefixes_of(groups), targets, strict=True)
        if t is not None
        for n in NAMES
    }
    meta = {"kind": "mdvae-distill-targets", "networks": digest,
            **file_key(groups, refine_steps)}  # fmt: skip
    save_checkpoint(path, tensors, meta)


def complete(targets: list[Targets | None], groups: list[WindowGroup]) -> bool:
    """Whether every group's windows all have their targets."""
    return all(t is not None and len(t) == len(g) for t, g in zip(targets, groups, strict=True))


def distill_targets(
    denoiser: Denoiser,
    groups: list[WindowGroup],
    refine_steps: int,
    out_dir: Path,
    fresh: bool,
    distilling: bool,
    progress: Callable[[dict], None] | None = None,
    stop_requested: Callable[[], bool] | None = None,
    keep_seconds: float = KEEP_SECONDS,
) -> list[Targets]:
    """The refined targets of a run, one per group: read back from ``out_dir`` when made for
    these windows and steps from these very networks (or, ``distilling`` — a resumed run part
    way through distillation — from the networks this run started from; ``fresh``: ELBO steps
    were just taken, never reuse), the missing ones made and saved there. ``stop_requested()``
    true after a batch of windows saves those made so far and returns them: then some group's
    targets cover only its first windows (:func:`complete` is False)."""
    path = Path(out_dir) / TARGETS_FILE
    digest = parameter_digest(denoiser)
    stored = None if fresh else stored_targets(path, groups, refine_steps, digest, distilling)
    targets: list[Targets | None] = list(stored) if stored else [None] * len(groups)
    if complete(targets, groups):
        return targets  # type: ignore[return-value]
    device = next(denoiser.parameters()).device
    denoiser.cpu()  # refinement runs batch by batch on the CPU copy of the windows
    saved_at = time.monotonic()

    def keep(i: int, so_far: Callable[[], Targets]) -> None:
        nonlocal saved_at
        if time.monotonic() - saved_at >= keep_seconds:
            made = [*targets[:i], so_far(), *targets[i + 1 :]]
            save_targets(path, groups, refine_steps, digest, made)
            saved_at = time.monotonic()

    for i, g in enumerate(groups):
        if targets[i] is not None and len(targets[i]) == len(g):
            continue
        targets[i] = refine_targets(
            denoiser, g, refine_steps, progress, start=targets[i],
            stop_requested=stop_requested, keep=lambda part, i=i: keep(i, part),
            workers=worker_count(),
        )  # fmt: skip
        if len(targets[i]) < len(g):  # stopped
            break
    denoiser.to(device)
    save_targets(path, groups, refine_steps, digest, targets)
    return targets  # type: ignore[return-value]


def windows_left(targets: list[Targets], groups: list[WindowGroup]) -> int:
    """Windows whose targets are still to be made."""
    return sum(len(g) - (0 if t is None else len(t)) for t, g in zip(targets, groups, strict=True))
