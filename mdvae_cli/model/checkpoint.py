"""Checkpoints that are safe to load: tensors in an .npz (no pickle) plus JSON metadata."""

from __future__ import annotations

import contextlib
import json
import signal
import threading
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.errors import InputError, Terminated
from mdvae_cli.fileio import check_regular, write_atomic
from mdvae_cli.npz_archive import read_npz


def save_checkpoint(path: Path, tensors: dict[str, torch.Tensor], meta: dict) -> None:
    """Write ``path`` (.npz of tensors) and ``path.with_suffix('.json')`` (meta), atomically."""
    path = Path(path)
    arrays = {k: v.detach().cpu().numpy() for k, v in tensors.items()}

    def write_npz(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    with interrupts_deferred():  # a Ctrl-C between the two leaves weights and meta unmatched
        write_atomic(path, write_npz)
        write_atomic(
            path.with_suffix(".json"),
            lambda tmp: tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n"),
        )


@contextlib.contextmanager
def float32_default():
    """torch's default dtype float32 inside the block, and as it was after: the networks are
    built, and the data they read made, in float32 whatever default a caller set
    (``torch.set_default_dtype(torch.float64)`` had left the networks in float64 beside
    windows made in float32). Also a decorator: ``@float32_default()``."""
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float32)
    try:
        yield
    finally:
        torch.set_default_dtype(before)


@contextlib.contextmanager
def interrupts_deferred():
    """Hold a Ctrl-C (SIGINT) or a SIGTERM back until the block is done, then raise
    KeyboardInterrupt (``errors.Terminated`` for SIGTERM) in the main thread (elsewhere Python
    delivers no signals anyway). An ignored signal (a background job's SIGINT) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = [s for s in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(s) is not signal.SIG_IGN]
    previous = {s: signal.signal(s, lambda signum, _: caught.append(signum)) for s in held}
    try:
        yield
    finally:
        for s, handler in previous.items():
            if handler is None:  # set outside Python: its default
                handler = signal.default_int_handler if s == signal.SIGINT else signal.SIG_DFL
            signal.signal(s, handler)
    if signal.SIGINT in caught:
        raise KeyboardInterrupt
    if caught:
        raise Terminated


#: bytes a checkpoint's weights may take together (the shipped denoiser: a few MB)
MAX_WEIGHT_BYTES = 512 << 20


def load_checkpoint(path: Path) -> tuple[dict[str, torch.Tensor], dict]:
    """Read a checkpoint written by :func:`save_checkpoint`; never unpickles anything."""
    path = Path(path)
    meta_path = path.with_suffix(".json")
    if not path.exists():
        raise InputError(f"checkpoint {path} not found")
    if not meta_path.exists():
        raise InputError(
            f"{path} is not an mdvae checkpoint: its metadata {meta_path.name} is not beside it"
        )
    check_regular(path)
    check_regular(meta_path)  # a FIFO beside it would make reading it wait forever
    arrays = read_npz(path, f"checkpoint {path}", max_total=MAX_WEIGHT_BYTES)
    for key, a in arrays.items():
        if a.dtype.kind not in "biufc":  # complex is refused with the weights' other checks
            what = "text" if a.dtype.kind in "US" else "values that are not numbers"
            raise InputError(f"checkpoint {path}: {key!r} holds {what}, not weights (is it a "
                             "checkpoint?)")  # fmt: skip
    tensors = {k: torch.from_numpy(a) for k, a in arrays.items()}
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"checkpoint {path}: cannot read its metadata {meta_path.name} "
                         f"({exc.strerror or exc})") from None  # fmt: skip
    except json.JSONDecodeError as exc:
        raise InputError(f"checkpoint {path}: its metadata {meta_path.name} is not valid JSON "
                         f"({exc.msg}, line {exc.lineno})") from None  # fmt: skip
    if not isinstance(meta, dict):
        raise InputError(f"checkpoint {path}: its metadata {meta_path.name} is not a JSON object")
    return tensors, meta


def load_weights(module: torch.nn.Module, state: dict[str, torch.Tensor], path: Path) -> None:
    """Load ``state`` into ``module``; InputError (one line) saying how many weights are
    missing, unexpected or of the wrong shape when they do not match the module."""
    own = module.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    wrong = [k for k in own if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
    parts = [f"{len(keys)} {what} (e.g. {keys[0]!r})" for keys, what in
             ((missing, "missing"), (unexpected, "unexpected"), (wrong, "of the wrong shape"))
             if keys]  # fmt: skip
    if parts:
        raise InputError(f"{path}: weights do not match its config: {', '.join(parts)}")
    for key in own:
        tensor = state[key]
        if tensor.is_complex() or not (tensor.is_floating_point() or tensor.dtype == torch.bool
                                       or not torch.is_floating_point(own[key])):  # fmt: skip
            raise InputError(f"{path}: weight {key!r} is {tensor.dtype}, not real numbers; the "
                             "checkpoint is damaged")  # fmt: skip
        if tensor.is_floating_point() and not torch.isfinite(tensor).all():
            raise InputError(f"{path}: weight {key!r} holds NaN or infinite values; the "
                             "checkpoint is damaged (use the shipped weights)")  # fmt: skip
    module.load_state_dict(state)
