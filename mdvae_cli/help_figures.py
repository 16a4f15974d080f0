"""The benchmark figures the help texts quote (``help_figures.json``, written by
``benchmarks/help_figures.py --write`` from the tables in ``docs/benchmarks.md``; never typed
by hand), and the way a help text writes them."""

from __future__ import annotations

import json
from pathlib import Path

FIGURES_FILE = Path(__file__).with_name("help_figures.json")


def help_figures() -> dict:
    """The figures, as the last benchmark runs gave them: ``denoise`` (speeds, the mirror's
    gain), ``outliers`` (``--outliers`` with ``--refine 50``), ``feet`` (the foot lock)."""
    return json.loads(FIGURES_FILE.read_text(encoding="utf-8"))


def span(pair: list[float], unit: str = "") -> str:
    """A measured range as help texts write it: ``5.5-9``, or ``8.4 %`` when both ends agree
    (``unit`` after the number, e.g. ``" %"``)."""
    lo, hi = (f"{x:g}" for x in pair)
    return f"{lo}{unit}" if lo == hi else f"{lo}-{hi}{unit}"
