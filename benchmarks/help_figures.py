"""The figures ``mdvae --help`` and the README quote, taken from the benchmarks' own tables.

    python benchmarks/help_figures.py           # exit 1 when the committed figures are stale
    python benchmarks/help_figures.py --write   # rewrite mdvae_cli/help_figures.json (and README)

The benchmark scripts write their tables into marked sections of ``docs/benchmarks.md``
(``benchmarks/denoise_table.py``, ``outliers.py``, ``feet.py``); every time one of them does,
``common.write_section`` calls :func:`write`, so ``mdvae_cli/help_figures.json`` (what the
help texts read, ``mdvae_cli.help_figures``) and the README's quotes follow the last run. No
figure in a help text is typed by hand.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path

try:
    from benchmarks.denoise_rows import ROW_OFFSET, ROW_REFINE, ROW_REFINE_MIRROR, ROW_REGRESSION
except ModuleNotFoundError:  # run as a file
    from denoise_rows import (  # type: ignore[no-redef]
        ROW_OFFSET,
        ROW_REFINE,
        ROW_REFINE_MIRROR,
        ROW_REGRESSION,
    )

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs" / "benchmarks.md"
FIGURES = REPO / "mdvae_cli" / "help_figures.json"
README = REPO / "README.md"

#: README phrases that quote a figure: pattern (one group: the number) -> the figure's key
_FPS_CELL = r"(?:[^|\n]*\|){3} ([\d,]+) \|"  # after a row's name, its fourth cell: frames/s
README_QUOTES = {
    r"most accurate \(~(\d+)x slower\)": ("denoise", "refine_mirror_slowdown"),
    r"\| best tuned filter \([^|\n]*\) \|" + _FPS_CELL: ("denoise", "filter_fps"),
    r"\| `--refine 50 --feet off` \|" + _FPS_CELL: ("denoise", "refine_fps"),
    r"\| `--refine 50 --mirror --feet off` \|" + _FPS_CELL: (
        "denoise",
        "refine_mirror_fps",
    ),
    r"the filter ran at ([\d,]+) frames/s here": ("denoise", "filter_fps"),
}


def section(text: str, name: str) -> str:
    """The body of the marked section ``<!-- name:begin (written ...) -->`` (the first one
    with no ``split=``: the test split)."""
    m = re.search(rf"<!-- {name}:begin \(written[^>]*-->(.*?)<!-- {name}:end -->", text, re.S)
    if m is None:
        raise ValueError(f"{DOCS.name}: no {name} section written by its benchmark")
    return m.group(1)


def tables(text: str) -> list[list[dict[str, str]]]:
    """Every markdown table in ``text`` as rows of {header: cell}."""
    out, rows = [], []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
            continue
        if len(rows) > 2:
            out.append([dict(zip(rows[0], r, strict=False)) for r in rows[2:]])
        rows = []
    return out


def row(rows: list[dict[str, str]], first: str) -> dict[str, str]:
    """The row whose first cell is ``first``."""
    for r in rows:
        if next(iter(r.values())) == first:
            return r
    raise ValueError(f"{DOCS.name}: no row {first!r}")


def number(cell: str, i: int = 0) -> float:
    """The ``i``-th number in a cell ("2.27 / 3.09", "11,659", "-8.4 %")."""
    return float(re.findall(r"-?\d[\d,]*\.?\d*(?:e-?\d+)?", cell)[i].replace(",", ""))


def sig(x: float, digits: int = 2) -> float:
    """``x`` to ``digits`` significant digits."""
    return float(f"{x:.{digits}g}")


def denoise_figures(text: str) -> dict:
    """Speeds and the mirror's gain from ``denoise_table.py``'s test-split table."""
    rows = tables(section(text, "denoise_table"))[0]
    fps = {name: number(row(rows, name)["frames/s ↑"])
           for name in (ROW_REGRESSION, ROW_OFFSET, ROW_REFINE, ROW_REFINE_MIRROR)}  # fmt: skip
    v2v = [c for c in rows[0] if c.startswith("V2V σ=")]
    refine, mirror = row(rows, ROW_REFINE), row(rows, ROW_REFINE_MIRROR)
    gains = [100 * (1 - number(mirror[c]) / number(refine[c])) for c in v2v]
    one_pass = fps[ROW_OFFSET]
    best = next(r for r in rows if r[list(r)[-1]] == "best filter")
    return {
        "filter_fps": round(number(best["frames/s ↑"])),
        "refine_fps": round(fps["Latent refinement"]),
        "refine_mirror_fps": round(fps["Latent refinement + mirror"]),
        "offset_time": round(fps["Regression mode"] / one_pass, 1),
        "refine_slowdown": round(one_pass / fps["Latent refinement"]),
        "refine_mirror_slowdown": round(one_pass / fps["Latent refinement + mirror"]),
        "mirror_time": round(fps["Latent refinement"] / fps["Latent refinement + mirror"], 1),
        "mirror_refine_gain_pct": [round(min(gains), 1), round(max(gains), 1)],
    }


def outlier_figures(text: str) -> dict:
    """What ``--outliers`` does with ``--refine 50``, from ``outliers.py``'s table."""
    rows = tables(section(text, "outliers"))[0]
    plain, heavy = row(rows, "`--refine 50`"), row(rows, "`--refine 50 --outliers`")
    change = {c: 100 * (number(heavy[c]) / number(plain[c]) - 1) for c in list(rows[0])[1:]}
    spikes = [-v for c, v in change.items() if "spikes" in c]
    even = [v for c, v in change.items() if "spikes" not in c]
    return {"spike_gain_pct": [round(min(spikes)), round(max(spikes))],
            "even_cost_pct": [round(min(even), 1), round(max(even), 1)]}  # fmt: skip


def feet_figures(text: str) -> dict:
    """The foot lock's targets table (σ 0.10-0.20) from ``feet.py``."""
    rows = tables(section(text, "feet"))[0]
    out: dict = {}
    for split in ("test", "unseen_test"):
        mine = [r for r in rows if r["split"] == split]
        skate = [[number(c, 0), number(c, 1)] for c in (r[_col(r, "skate /")] for r in mine)]
        v2v = [-number(r[_col(r, "lock vs off")]) for r in mine]
        out[split] = {
            "skate_off": [sig(min(s[0] for s in skate)), sig(max(s[0] for s in skate))],
            "skate_lock": [sig(min(s[1] for s in skate)), sig(max(s[1] for s in skate))],
            "v2v_gain_pct": [round(min(v2v), 1), round(max(v2v), 1)],
        }
    long = [number(r[_col(r, "one long take")]) for r in rows if r[_col(r, "one long take")] != "-"]
    out["ms_per_frame"] = [sig(min(long)), sig(max(long))]
    return out


def _col(r: dict, start: str) -> str:
    return next(c for c in r if start in c)


def figures(text: str) -> dict:
    """Every figure the help texts quote, from the text of ``docs/benchmarks.md``."""
    return {
        "source": "written by benchmarks/help_figures.py --write from the tables the benchmarks "
        "wrote into docs/benchmarks.md; not edited by hand",
        "denoise": denoise_figures(text),
        "outliers": outlier_figures(text),
        "feet": feet_figures(text),
    }


def readme_text(readme: str, figs: dict) -> str:
    """The README with every quoted figure (:data:`README_QUOTES`) set to the table's."""
    for pattern, (group, key) in README_QUOTES.items():
        value = f"{figs[group][key]:,}"  # 15,199 as the README writes it

        def put(m: re.Match, value: str = value) -> str:
            return (
                m.group(0)[: m.start(1) - m.start(0)] + value + m.group(0)[m.end(1) - m.start(0) :]
            )

        readme = re.sub(pattern, put, readme)
    return readme


def write(docs: Path = DOCS) -> bool:
    """Rewrite the figures file and the README's quotes from ``docs``; whether anything
    changed."""
    figs = figures(docs.read_text(encoding="utf-8"))
    text = json.dumps(figs, indent=2, ensure_ascii=False) + "\n"
    old = FIGURES.read_text(encoding="utf-8") if FIGURES.exists() else ""
    readme = README.read_text(encoding="utf-8")
    new_readme = readme_text(readme, figs)
    if text != old:
        FIGURES.write_text(text, encoding="utf-8")
    if new_readme != readme:
        README.write_text(new_readme, encoding="utf-8")
    return text != old or new_readme != readme


def stale(docs: Path = DOCS) -> list[str]:
    """What is out of date with the tables in ``docs`` (empty: nothing)."""
    figs = figures(docs.read_text(encoding="utf-8"))
    out = []
    if json.loads(FIGURES.read_text(encoding="utf-8")) != figs:
        out.append(str(FIGURES.relative_to(REPO)))
    readme = README.read_text(encoding="utf-8")
    if readme_text(readme, figs) != readme:
        out.append(str(README.relative_to(REPO)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--write", action="store_true", help="rewrite the figures and the README")
    args = p.parse_args(argv)
    if args.write:
        print("updated" if write() else "up to date")
        return 0
    late = stale()
    if late:
        print(f"stale: {', '.join(late)}; run python benchmarks/help_figures.py --write")
    return 1 if late else 0


if __name__ == "__main__":
    sys.exit(main())
