"""Guards every training loop shares: the device a ``--device`` value names, what happens when
a loss or the weights stop being finite (the run ends before anything of them is saved), and
JSON that stays strict (no nan or inf), and a new run that would land on an old one."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import torch

from mdvae_cli.errors import InputError
from mdvae_cli.train.distributed import DistInfo


def check_device(name) -> None:
    """InputError unless ``name`` is auto, cpu, cuda or cuda:N."""
    if not (isinstance(name, str) and re.fullmatch(r"auto|cpu|cuda(:\d+)?", name)):
        raise InputError(f"--device must be auto, cpu, cuda or cuda:N, got {name!r}")


def pick_device(name: str) -> torch.device:
    """The torch device of a ``--device`` value; InputError for a GPU this machine lacks."""
    check_device(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise InputError(f"--device {name}: no CUDA GPU is available here; use cpu or auto")
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise InputError(f"--device {name}: this machine has {count} CUDA GPU(s), cuda:0..")
    return device


def loss_is_finite(loss: torch.Tensor, dist: DistInfo | None = None) -> bool:
    """Whether a step's loss is finite (under DDP: on every rank, so that all stop together)."""
    ok = torch.isfinite(loss.detach()).all().float()
    if dist is not None and dist.enabled:
        torch.distributed.all_reduce(ok, op=torch.distributed.ReduceOp.MIN)
    return bool(ok)


def weights_are_finite(module: torch.nn.Module) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in module.state_dict().values())


def json_safe(value):
    """``value`` with every nan/inf float replaced by None (strict JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


#: the files that mark a run folder, by the command that writes it
RUN_FILES = {"train-prior": ("last.npz", "best.npz"), "fit-dataset": ("denoiser.npz",)}


def refuse_to_overwrite(run_dir, command: str, option: str = "", replace: bool = False) -> None:
    """InputError when ``run_dir`` already holds a run of ``command`` (its :data:`RUN_FILES`):
    a new run there would mix its files with the old one's; ``--resume`` continues it, and
    ``option`` (e.g. "--overwrite"), where the command has one, replaces it (``replace``: it was
    given). A run of another command there is refused whatever the options: a new run would
    overwrite its config.json, so that it could never be resumed."""
    for other, marks in RUN_FILES.items():
        held = [n for n in marks if (Path(run_dir) / n).exists()]
        if held and other != command:
            raise InputError(f"{run_dir} holds a {other} run ({', '.join(held)}): give "
                             "another folder")  # fmt: skip
        if held and not replace:
            also = f", {option} to replace it" if option else ""
            raise InputError(
                f"{run_dir} already holds a run ({', '.join(held)}): add --resume to continue it"
                f"{also}, or give another folder"
            )


def checkpoint_to_resume(run_dir, name: str) -> Path:
    """``run_dir / name``, or InputError when a run stopped before saving it (nothing to
    resume: the run starts again without --resume)."""
    path = Path(run_dir) / name
    if not path.exists():
        raise InputError(
            f"nothing to resume in {run_dir}: it has no {name} yet (the run stopped before its "
            "first save); start it again without --resume"
        )
    return path


def check_run_folder(run_dir) -> None:
    """InputError when ``run_dir`` cannot become a run folder (a file, or inside a folder
    that cannot be written: a read-only disk), said before the data are read, which can take
    minutes; the folder itself is made only once they are good."""
    run_dir = Path(run_dir)
    here = run_dir
    while not here.exists() and here != here.parent:
        here = here.parent
    where = f"{run_dir}: {here}" if here != run_dir else f"{run_dir}"
    if here.exists() and not here.is_dir():
        raise InputError(f"{where} is a file, not a folder")
    if here.exists() and not os.access(here, os.W_OK | os.X_OK):
        raise InputError(f"{where} cannot be written in (read-only or not yours)")
