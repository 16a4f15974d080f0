"""SIGTERM (``timeout``, ``kill``, job schedulers) stops a run as Ctrl-C does: one line, exit
143, and no half-written output left behind."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from mdvae_cli.cli.main import cli, raise_on_sigterm
from mdvae_cli.errors import Terminated
from mdvae_cli.fileio import write_atomic
from mdvae_cli.model.checkpoint import interrupts_deferred


@pytest.fixture
def sigterm_raises():
    previous = signal.getsignal(signal.SIGTERM)
    raise_on_sigterm()
    yield
    signal.signal(signal.SIGTERM, previous)


def _term_self() -> None:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(2)  # the handler runs here, in the main thread


def test_a_sigterm_mid_write_leaves_no_partial_file(tmp_path, sigterm_raises):
    def half_then_killed(tmp):
        tmp.write_bytes(b"HIERARCHY\nROOT Hips\n")
        _term_self()

    started = time.perf_counter()
    with pytest.raises(Terminated):
        write_atomic(tmp_path / "out" / "take.bvh", half_then_killed)
    assert time.perf_counter() - started < 1.5  # raised at once, not after the sleep
    assert list(tmp_path.iterdir()) == []  # neither the temporary nor the folder made for it


def test_a_checkpoint_write_finishes_before_a_sigterm_stops_it(tmp_path, sigterm_raises):
    done = []
    with pytest.raises(Terminated), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        done.append(True)
    assert done == [True]
    assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # the raising handler again


def test_the_command_line_says_terminated_with_143(make_motion_file, tmp_path, monkeypatch, capsys):
    clean = make_motion_file("clean.npz", T=12)
    from mdvae_cli import metrics

    def stopped(*args, **kwargs):
        raise Terminated

    monkeypatch.setattr(metrics, "evaluate_pair", stopped)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit) as exit_:
            cli.main(["eval", "--gt", str(clean), "--pred", str(clean)], prog_name="mdvae")
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert exit_.value.code == 143
    err = capsys.readouterr()
    lines = [ln for ln in (err.out + err.err).splitlines() if ln.strip()]
    assert lines[-1] == "error: terminated" and not any("Traceback" in ln for ln in lines)
    assert np.load(clean)["poses"].shape[0] == 12  # the input as it was
