"""The figures in the help texts and the README come from the benchmarks' tables
(``benchmarks/help_figures.py`` -> ``mdvae_cli/help_figures.json``), never typed by hand."""

from __future__ import annotations

import re

from benchmarks import help_figures as generator
from mdvae_cli.cli.denoise import denoise
from mdvae_cli.help_figures import help_figures, span


def option_help() -> dict[str, str]:
    return {p.name: " ".join(p.help.split()) for p in denoise.params if getattr(p, "help", None)}


def test_the_committed_figures_are_the_benchmark_tables():
    assert generator.stale() == []  # else: python benchmarks/help_figures.py --write


def test_the_help_quotes_the_table():
    helps, f = option_help(), help_figures()
    d, o, feet = f["denoise"], f["outliers"], f["feet"]
    assert f"about {d['refine_slowdown']:g}x slower" in helps["refine_steps"]
    assert f"~{d['offset_time']:g}x the time" in helps["offset"]
    assert f"{span(d['mirror_refine_gain_pct'], ' %')} lower error" in helps["mirror"]
    assert f"{d['mirror_time']:g}x the time" in helps["mirror"]
    assert (
        f"{span(o['spike_gain_pct'], ' %')} lower error on takes with spikes" in helps["outliers"]
    )
    assert f"{span(o['even_cost_pct'], ' %')} higher" in helps["outliers"]
    for split in ("test", "unseen_test"):
        for key in ("skate_off", "skate_lock"):
            assert span(feet[split][key]) in helps["feet"]
        assert span(feet[split]["v2v_gain_pct"], " %") in helps["feet"]
    assert f"~{span(feet['ms_per_frame'])} ms a frame" in helps["feet"]


def test_no_speed_or_gain_in_a_help_text_is_typed_by_hand():
    flat = json_numbers(help_figures())
    for name, text in option_help().items():
        quoted = re.findall(
            r"(\d+(?:\.\d+)?)(?:-\d+(?:\.\d+)?)? ?(?:x slower|x the time|ms a frame|% )", text
        )
        assert {float(q) for q in quoted} <= flat, name


def json_numbers(data) -> set[float]:
    if isinstance(data, dict):
        return set().union(*(json_numbers(v) for v in data.values()))
    if isinstance(data, list):
        return set().union(*(json_numbers(v) for v in data))
    return {float(data)} if isinstance(data, int | float) else set()


def test_the_readme_quotes_the_table():
    readme = generator.README.read_text(encoding="utf-8")
    slowdown = help_figures()["denoise"]["refine_mirror_slowdown"]
    assert f"most accurate (~{slowdown:g}x slower)" in readme


def test_the_figures_follow_the_table():
    text = generator.DOCS.read_text(encoding="utf-8")
    before = generator.figures(text)["denoise"]
    # refinement twice as slow in the table: twice the slowdown in the help
    refine = re.search(r"\| Latent refinement \|[^\n]*", text).group(0)
    cells = refine.split("|")
    cells[4] = f" {float(cells[4].replace(',', '')) / 2:.0f} "
    after = generator.figures(text.replace(refine, "|".join(cells)))["denoise"]
    assert after["refine_slowdown"] == round(2 * before["refine_slowdown"])
    assert after["mirror_time"] == round(before["mirror_time"] / 2, 1)


def test_a_range_is_written_once_when_its_ends_agree():
    assert span([5.5, 9.0]) == "5.5-9"
    assert span([40, 40], " %") == "40 %"


def test_every_readme_quote_is_found_and_follows_the_table():
    readme = generator.README.read_text(encoding="utf-8")
    figs = help_figures()
    for pattern, (group, key) in generator.README_QUOTES.items():
        found = re.findall(pattern, readme)
        assert found and {int(x.replace(",", "")) for x in found} == {figs[group][key]}, key
        moved = {**figs, group: {**figs[group], key: figs[group][key] + 1000}}
        assert f"{figs[group][key] + 1000:,}" in generator.readme_text(readme, moved), key
