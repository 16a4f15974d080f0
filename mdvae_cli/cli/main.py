"""The ``mdvae`` entry point: registers one small module per command."""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading
from typing import NoReturn

import click

from mdvae_cli import __version__
from mdvae_cli.cli import (
    add_noise,
    denoise,
    eval_cmd,
    export_bvh,
    export_mesh,
    fit_dataset_cmd,
    import_cmd,
    sample,
    train,
    view_cmd,
)
from mdvae_cli.cli.common import fail
from mdvae_cli.errors import Terminated, stop_words


def _terminate(signum, frame) -> None:
    raise Terminated


def raise_on_sigterm() -> None:
    """Turn SIGTERM into :class:`Terminated` in the main thread (unless it is ignored), so that
    a stopped run cleans up as Ctrl-C does."""
    if threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN:
            signal.signal(signal.SIGTERM, _terminate)


class OneLineErrors(click.Group):
    """The ``mdvae`` group: a bad option value, a missing argument or an unknown option is one
    ``error: ...`` line naming the command's help, with exit code 1 (as every other refusal),
    instead of Click's usage block with exit code 2."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        raise_on_sigterm()
        as_json = "--json" in (sys.argv[1:] if args is None else args)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # bare ``mdvae``: the help (Click 8.2)
                click.echo(exc.format_message())
                sys.exit(0)
            where = exc.ctx.command_path if exc.ctx is not None else "mdvae"
            fail(f"{exc.format_message()} (see {where} -h)", as_json=as_json)
        except click.exceptions.Abort as exc:  # Click's wrapping of a KeyboardInterrupt
            stop = exc.__context__
            stop = stop if isinstance(stop, KeyboardInterrupt) else KeyboardInterrupt()
            fail(*stop_words(stop), as_json=as_json)
        except click.ClickException as exc:
            fail(exc.format_message(), as_json=as_json)
        sys.exit(code if isinstance(code, int) else 0)


@click.group(cls=OneLineErrors, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mdvae")
def cli() -> None:
    """Clean up human motion-capture files with a learned motion prior (Motion-DVAE).

    \b
    Typical pipeline:
      mdvae add-noise --sigma 0.15 clean.npz -o noisy.npz
      mdvae denoise noisy.npz -o cleaned.npz
      mdvae eval --gt clean.npz --pred cleaned.npz

    Files are AMASS-style .npz (poses, trans, betas, mocap_framerate), BVH and ASF/AMC takes,
    or the outputs of video pose pipelines (WHAM, GVHMR, ...). Every file command takes files
    or folders (folders are mirrored into the output folder) and answers --json.
    """


for module in (
    train,
    fit_dataset_cmd,
    denoise,
    add_noise,
    eval_cmd,
    export_bvh,
    export_mesh,
    import_cmd,
    sample,
    view_cmd,
):
    for command in module.COMMANDS:
        cli.add_command(command)


def exit_now(code: int | str | None) -> NoReturn:
    """End the process with ``code`` (as ``sys.exit`` reads it) without the interpreter's
    teardown: the exit handlers run (logging, temporary folders) and the standard streams
    are flushed, then the process ends. Tearing torch down costs a quarter of a second of
    every command (`python -c "import torch"`: 1.05 s against 0.81 s), and every output is
    written and closed by then."""
    if code is None:
        code = 0
    elif not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more to say
            pass
    os._exit(code)


def main() -> NoReturn:
    """The ``mdvae`` console script: :func:`cli`, then :func:`exit_now` (an error no command
    caught still ends with its traceback, as Python ends it)."""
    try:
        cli()
        code: int | str | None = 0
    except SystemExit as exc:
        code = exc.code
    exit_now(code)


if __name__ == "__main__":  # pragma: no cover
    main()
