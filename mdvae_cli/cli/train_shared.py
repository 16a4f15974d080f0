"""What the training commands (``train-prior``, ``fit-dataset``) share: progress reporting,
the config a run starts from, command-line overrides, the summary as JSON."""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import threading
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

import click

from mdvae_cli.cli.batch import note_broken_links
from mdvae_cli.cli.common import SEED, console
from mdvae_cli.errors import InputError, Terminated
from mdvae_cli.fileio import MOTION_SUFFIXES, expand_inputs


class StepReporter:
    """Feeds training progress dicts into a rich progress bar."""

    def __init__(self, progress, label: str):
        self.progress = progress
        self.label = label
        self.task = None
        self.terms = ""

    def __call__(self, info: dict) -> None:
        if "note" in info:
            console.print(f"note: {info['note']}")
            return
        if info.get("epoch_end"):
            val = info.get("val") or {}
            text = "  ".join(f"{k} {v:.3f}" for k, v in val.items())
            if not val and "train_loss" in info:  # a run without validation windows
                text = f"none; train loss {info['train_loss']:.3f}"
            console.print(f"epoch {info['epoch'] + 1}: val {text}")
            return
        total = info["steps_per_epoch"] * info["epochs"]
        if self.task is None:
            self.task = self.progress.add_task(self.label, total=total, info="")
        if "loss" in info:  # steps without the loss terms keep the last ones shown
            self.terms = "  ".join(
                f"{k} {info[k]:.3f}" for k in ("loss", "recon", "kl", "body_cm2") if k in info
            )
        terms = self.terms
        self.progress.update(
            self.task, completed=info["step"], info=f"ep {info['epoch'] + 1} {terms}"
        )
        if not console.is_terminal and info["step"] % 50 == 0:  # logs of batch jobs
            console.print(f"step {info['step']}/{total} ep {info['epoch'] + 1} {terms}")


def note_skipped_data(paths) -> None:
    """``note:`` lines for what the trainer leaves out of the folders among ``paths``: broken
    links, and motion files of other formats than AMASS-style .npz (BVH, AMC, video
    pipelines' files), which ``mdvae import`` converts."""
    from mdvae_cli.formats.registry import READ_SUFFIXES

    note_broken_links(paths)
    folders = [Path(p) for p in paths if Path(p).is_dir()]
    others = [f for f, _ in expand_inputs(folders, READ_SUFFIXES)
              if not f.name.lower().removesuffix(".gz").endswith(MOTION_SUFFIXES)]  # fmt: skip
    if others:
        kinds = sorted({f.name.lower().removesuffix(".gz").rsplit(".", 1)[-1] for f in others})
        console.print(
            f"[dim]note: {len(others)} file(s) of other formats ({', '.join(kinds)}) left out: "
            f"training reads AMASS-style .npz; `mdvae import {' '.join(map(str, folders))} -o "
            "imported/` converts them[/]",
            soft_wrap=True,
        )


def start_config(cls, run_dir: Path, resume: bool, config_file: Path | None, data=None):
    """The config to run: the run's own (resume; the ``data`` paths given must be its own),
    a given file, or the defaults."""
    if resume:
        path = Path(run_dir) / "config.json"
        if not path.exists():
            raise InputError(f"nothing to resume: {path} not found")
    else:
        path = config_file
    if path is None:
        return cls()
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"config {path} is unreadable ({exc})") from None
    if resume and isinstance(d, dict) and not set(d) <= {f.name for f in fields(cls)}:
        key = sorted(set(d) - {f.name for f in fields(cls)})[0]
        raise InputError(
            f"{run_dir} is not a run of this command ({path.name} has the key {key!r}): "
            "resume it with the command that wrote it"
        )
    # a run's own config.json was written by mdvae (an option it lacks predates it, a nested
    # key it has no more is an old option); a config a user wrote leaves out what should take
    # its default, and every key it names must exist
    cfg = cls.from_dict(d, legacy=resume, source=f"config {path}")
    if resume and data is not None:
        same_data_on_resume(cfg.data, data, run_dir)
    return cfg


def same_path(given, saved) -> bool:
    """Whether a path given on --resume is the one the run's config.json holds."""
    return saved is not None and Path(given).resolve() == Path(saved).resolve()


def same_config(cls, config_file: Path, cfg, overridden=()) -> bool:
    """Whether a ``--config`` file given on --resume says what the run's own config holds for
    every setting it names but those an option given now sets (``overridden``): the command
    as first run, given again."""
    given = start_config(cls, Path("."), False, config_file)
    named = json.loads(Path(config_file).read_text())
    return isinstance(named, dict) and all(
        getattr(given, k) == getattr(cfg, k)
        for k in named
        if hasattr(cfg, k) and k not in overridden
    )


def refuse_changes_on_resume(given: dict[str, tuple[object, bool]]) -> None:
    """InputError naming the options given on --resume that say other than the run's own
    config.json (``given``: option -> (its value or None, whether that is the run's))."""
    named = ", ".join(k for k, (v, same) in given.items() if v is not None and not same)
    if named:
        raise InputError(f"{named} cannot change when resuming (the run's config.json has it)")


def same_data_on_resume(saved: list[str], given, run_dir: Path) -> None:
    """InputError when a resumed run is given other data paths than its config.json holds
    (the run reads its own: the paths given would be ignored)."""
    if sorted({Path(p).resolve() for p in saved}) != sorted({Path(p).resolve() for p in given}):
        raise InputError(
            f"the data paths cannot change when resuming: the run in {run_dir} reads "
            f"{' '.join(saved)} (its config.json); give those, or start a new run"
        )


#: options a resumed run cannot change, its checkpoint keeping them: train-prior's velocity
#: scale (in the normaliser), whether fit-dataset's networks read holes (their hole reader)
FROZEN_ON_RESUME = ("velocity_std_scale", "holes")


def apply_overrides(
    cfg, overrides: dict, nested: dict[str, str | tuple[str, str]], resume: bool
) -> None:
    """Set the options given on the command line; ``nested`` maps an option to the sub-config
    holding it (same field name) or to (sub-config, field).

    On resume, options of the networks the run continues are refused: their shape (``model``),
    a denoiser's settings (``denoiser``) and :data:`FROZEN_ON_RESUME`.
    """
    for key, value in overrides.items():
        if value is None:
            continue
        where = nested.get(key)
        sub, name = (where, key) if where is None or isinstance(where, str) else where
        target = cfg if sub is None else getattr(cfg, sub)
        kept = sub in ("model", "denoiser") or key in FROZEN_ON_RESUME
        if resume and kept and getattr(target, name) != value:
            raise InputError(f"--{key.replace('_', '-')} cannot change when resuming a run")
        setattr(target, name, value)


def run_options(fn: Callable) -> Callable:
    """The options train-prior and fit-dataset share: --config, --seed, --device, --threads,
    --json."""
    for option in reversed(
        [
            click.option(
                "--config",
                "config_file",
                type=click.Path(path_type=Path, exists=True),
                help="A config.json to start from; options given here override it.",
            ),
            click.option("--seed", type=SEED, help="Random seed [default: 0]."),
            click.option("--device", help="auto, cpu, cuda or cuda:N [default: auto]."),
            click.option(
                "--threads", type=click.IntRange(1, 256), help="CPU threads for torch (1 to 256)."
            ),
            click.option(
                "--json",
                "as_json",
                is_flag=True,
                help="Print the run's summary as JSON on stdout (for pipelines).",
            ),  # fmt: skip
        ]
    ):
        fn = option(fn)
    return fn


def summary_dict(summary) -> dict:
    """A run's summary dataclass for ``--json`` (numbers that are not finite as null)."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in dataclasses.asdict(summary).items()}  # fmt: skip


class StopAfterStep:
    """While in use (a context manager), the first Ctrl-C or SIGTERM asks a training run to
    stop after its current step and save a checkpoint that ``--resume`` continues (the run
    polls the instance: it is the ``stop_requested`` callable); a second one stops at once, as
    a signal does elsewhere. ``raise_stop`` afterwards ends the command as the signal would
    have (exit 130 / 143)."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._previous: dict = {}

    def __call__(self) -> bool:
        return self.signal is not None

    def _caught(self, signum: int, frame) -> None:
        if self.signal is not None:  # the second: at once
            raise KeyboardInterrupt if signum == signal.SIGINT else Terminated
        self.signal = signum
        console.print("[yellow]stopping after this step[/] and saving a checkpoint that "
                      "--resume continues (again to stop at once)", soft_wrap=True)  # fmt: skip

    def __enter__(self) -> StopAfterStep:
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                if signal.getsignal(s) is not signal.SIG_IGN:
                    self._previous[s] = signal.signal(s, self._caught)
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            if handler is None:  # set outside Python: its default
                handler = signal.default_int_handler if s == signal.SIGINT else signal.SIG_DFL
            signal.signal(s, handler)

    def raise_stop(self, step: int | str, saved: str = "last.npz") -> None:
        """Exit as the caught signal would (after the run saved its checkpoint ``saved`` at
        ``step``)."""
        if self.signal is None:
            return
        console.print(f"stopped at step {step}; the run's {saved} continues it with --resume",
                      soft_wrap=True)  # fmt: skip
        raise KeyboardInterrupt if self.signal == signal.SIGINT else Terminated
