"""Report writing: files, self-contained HTML, Markdown, partial marking, unwritable folders, lazy matplotlib."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

from studyctl.analysis import ROW_COLUMNS, MetricTable, run_plan
from studyctl.analysis.plan import load_plan
from studyctl.analysis.results import FigureData
from studyctl.errors import ConfigError
from studyctl.report import ensure_writable, write_report

PLAN = """\
version: 1
study: toy
title: Toy study
conditions: [{id: A, label: Condition A}, {id: B, label: Condition B}, {id: C, label: Condition C}]
groups: [g1, g2]
metrics:
  time: {metric: completion_time}
  found: {metric: sensitivity}
  score: {metric: likert}
tests:
  - id: groups
    test: rank_sum
    metrics: [time]
    compare: group
    by: [condition]
  - id: kw
    test: kruskal_wallis
    metrics: [time]
    compare: condition
    posthoc: {test: dunn, when: always}
  - id: se
    test: wilson
    metrics: [found]
    compare: condition
  - id: pct
    test: percent_change
    metrics: [time]
    compare: condition
    reference: A
  - id: likert
    test: likert_table
    metrics: [score]
    compare: condition
    by: [item]
figures:
  - {id: box, kind: box, metrics: [time], by: [condition, group], marks: kw, title: Times}
  - {id: prop, kind: proportion, metrics: [found], by: [condition, nodule], title: Found}
  - {id: change, kind: percent_change, metrics: [time], title: Change, options: {test: pct}}
  - {id: lik, kind: likert, metrics: [score], by: [condition, item], title: Likert}
  - {id: trace, kind: force_trace, title: Trace}
"""


def toy_table(rng: np.random.Generator) -> pd.DataFrame:
    rows = []
    for i in range(12):
        g = "g1" if i < 6 else "g2"
        for k, c in enumerate("ABC"):
            base = {"participant": f"P{i}", "group": g, "condition": c, "trial": f"{i}{c}", "repetition": 1}
            rows.append(
                {
                    **base,
                    "metric": "completion_time",
                    "level": None,
                    "value": 30 + 5 * k + rng.normal(0, 4),
                    "denominator": np.nan,
                }
            )
            for n in ("n1", "n2"):
                rows.append(
                    {
                        **base,
                        "metric": "sensitivity",
                        "level": n,
                        "value": float(rng.random() < 0.7),
                        "denominator": 1.0,
                    }
                )
            for item in ("easy", "confident"):
                rows.append(
                    {
                        **base,
                        "metric": "likert",
                        "level": item,
                        "value": float(rng.integers(1, 6)),
                        "denominator": np.nan,
                    }
                )
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "toy.yaml"
    path.write_text(PLAN)
    return run_plan(load_plan(path), MetricTable(frame=toy_table(np.random.default_rng(5)), source="toy table"))


@pytest.fixture(scope="module")
def written(result, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    trace = FigureData(
        pd.DataFrame(
            {
                "panel": "A",
                "x": np.linspace(-1, 1, 50),
                "force_n": np.linspace(0, 2, 50),
                "contact": np.linspace(0, 2, 50) > 1,
            }
        ),
        meta={"channels": [("force_n", "force (N)", "left")], "shade": "contact", "threshold": 1.0},
    )
    return write_report(result, out, figure_data={"trace": trace})


@pytest.mark.slow
def test_files_written(written):
    out = written.out_dir
    names = sorted(p.name for p in out.iterdir())
    for name in (
        "tests.csv",
        "cells.csv",
        "units.csv",
        "proportions.csv",
        "percent_change.csv",
        "likert.csv",
        "missing.csv",
        "report.html",
        "report.md",
        "summary.json",
        "figures",
    ):
        assert name in names, name
    assert sorted(p.name for p in (out / "figures").iterdir()) == sorted(
        f"{i}.{fmt}" for i in ("box", "prop", "change", "lik", "trace") for fmt in ("png", "svg", "pdf")
    )
    magic = {".png": b"\x89PNG\r\n\x1a\n", ".svg": b"<?xml ve", ".pdf": b"%PDF-1.4"}
    for path in (out / "figures").iterdir():
        assert path.read_bytes()[:8] == magic[path.suffix], path.name
    assert not [p for p in out.rglob(".*") if p.is_file()], "temporary files left behind"


def test_tests_csv_is_tidy(written, result):
    frame = pd.read_csv(written.out_dir / "tests.csv")
    assert list(frame.columns) == list(ROW_COLUMNS)
    assert len(frame) == len(result.rows)
    assert set(frame["test_id"]) == {"groups", "kw", "se"}
    assert frame.loc[frame.test_id == "kw", "kind"].tolist() == ["omnibus", "posthoc", "posthoc", "posthoc"]


def test_html_is_self_contained(written):
    html = written.html.read_text()
    assert html.count("data:image/png;base64,") == 5
    assert "src='http" not in html and 'src="http' not in html and "<link" not in html
    assert "Toy study" in html and "Kruskal-Wallis" in html
    assert "Within-subject" not in html  # the toy plan has no within-subject entries


def test_markdown_links_figures_and_has_tables(written):
    md = written.markdown.read_text()
    assert "![Times](figures/box.png)" in md
    assert "| metric | condition | comparison | U | p | r_rb | significant |" in md  # split as its own column
    assert "| item | A | B | C |" in md  # the Likert table: items × conditions


@pytest.mark.slow
def test_missing_figure_data_marks_the_report_partial(result, tmp_path):
    files = write_report(result, tmp_path)
    assert files.partial
    assert any(p.startswith("figure trace:") for p in files.problems)
    assert "PARTIAL RESULTS" in files.html.read_text()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["partial"] is True and summary["problems"]


def test_complete_report_is_not_marked_partial(written):
    assert not written.partial
    assert "PARTIAL RESULTS" not in written.html.read_text()


def test_unwritable_output_folder(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match=r"cannot write the report to '.*a_file/out'.*choose a writable folder"):
        ensure_writable(blocker / "out")
    with pytest.raises(ConfigError, match="it exists and is not a folder"):
        ensure_writable(blocker)


@pytest.mark.slow
def test_matplotlib_is_imported_only_by_report_figures():
    code = textwrap.dedent("""
        import sys
        import studyctl.analysis, studyctl.report, studyctl.cli.app
        print('matplotlib' in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _html_tables(html: str) -> list[list[str]]:
    import re

    return [re.findall(r"<th>(.*?)</th>", head) for head in re.findall(r"<thead><tr>(.*?)</tr></thead>", html)]


def test_layout_title_toc_summary_then_tables(written):
    html = written.html.read_text()
    toc, summary, first_table = html.index("Contents"), html.index('id="summary"'), html.index("<table>")
    assert toc < summary < first_table
    # The headline of the Kruskal-Wallis entry is an APA line in the summary, before any table.
    assert html.index("H(2) = ") < first_table
    for anchor in ("summary", "methods", "descriptives", "kw", "figures", "missing"):
        assert f'href="#{anchor}"' in html and f'id="{anchor}"' in html


def test_tables_are_tidy(written):
    html = written.html.read_text()
    for head in _html_tables(html):
        assert len(head) == len(set(head)), head  # no column twice
        assert "split" not in head and "kind" not in head  # the split is named by its factor
    # p-values as journals print them: never in scientific notation
    import re

    cells = re.findall(r"<td>(.*?)</td>", html)
    assert not [c for c in cells if re.fullmatch(r"-?[0-9.]+e-?[0-9]+", c)]
    # and a bound keeps its sign on the number's line in a narrow column (a no-break space)
    assert "<td>&lt;\u00a0.001</td>" in html and "<td>&lt; .001</td>" not in html


def test_a_bound_or_a_df_pair_keeps_one_line_in_a_table_cell():
    from studyctl.report.render import _html_cell

    assert [_html_cell(c) for c in ("< .001", "> .999", "4, 44", "3, 41.5", "BL, RT, ES", "a < b", "4, 44 (GG)")] \
        == ["<\u00a0.001", ">\u00a0.999", "4,\u00a044", "3,\u00a041.5", "BL, RT, ES", "a < b", "4, 44 (GG)"]


def test_methods_paragraph_names_the_tests_and_software(written):
    md = written.markdown.read_text()
    methods = md[md.index("## Statistical methods"):md.index("## Descriptive")]
    assert "Kruskal-Wallis" in methods and "holm" in methods and "scipy " in methods and "statsmodels " in methods


def test_no_absolute_path_in_the_documents(tmp_path):
    from studyctl.report.document import relative_source

    src = str(tmp_path / "ws" / "study.db") + " (study 'x')"
    assert relative_source(src, tmp_path / "report") == "../ws/study.db (study 'x')"
    assert relative_source(src, None) == "study.db (study 'x')"
    assert relative_source("/usr/share/x/y/z/data.csv", tmp_path / "a" / "b" / "c") == "data.csv"
    assert relative_source("toy table", tmp_path) == "toy table"


def test_apa_lines():
    from studyctl.report import apa

    row = {"kind": "omnibus", "test": "anova_oneway", "statistic_name": "F", "statistic": 174.2, "df": 4.0,
           "df2": 55.0, "p": 2.17e-31, "p_adj": float("nan"), "p_adjust": "none", "effect_size_name": "eta_squared",
           "effect_size": 0.927, "z": float("nan"), "critical_value": float("nan")}
    assert apa.line(row) == "F(4, 55) = 174.2, p < .001, η² = .93"
    assert apa.p_text(0.0234) == "p = .023" and apa.p_text(0.9999) == "p > .999" and apa.p_text(float("nan")) == ""
    assert apa.bounded(-0.414) == "−.41"
    tukey = {"kind": "posthoc", "statistic_name": "diff (second − first)", "statistic": -3.75, "p_adj": 0.003,
             "p_adjust": "tukey", "effect_size_name": "mean_difference", "effect_size": -3.75, "ci_low": -4.2,
             "ci_high": -3.3, "ci_level": 0.95}
    assert apa.line(tukey) == "Δ = −3.75, 95% CI [−4.20, −3.30], p_tukey = .003"
    assert apa.line({"status": "not_computed"}) == "not computed"


def test_cli_text_output_shows_the_split(result):
    import io

    from rich.console import Console

    from studyctl.report.terminal import analysis_tables

    buf = io.StringIO()
    console = Console(file=buf, width=160, highlight=False)
    for table in analysis_tables(result):
        console.print(table)
    text = buf.getvalue()
    block = text[text.index("groups:"):text.index("kw:")]
    for level in ("A", "B", "C"):  # the condition of each rank-sum row (rich once swallowed "[condition=A]")
        assert f"\n{level} " in block.replace(" ", " ") or f"\n{level}  " in block


def test_figures_for_print(written):
    import struct

    png = (written.out_dir / "figures" / "box.png").read_bytes()
    width, height = struct.unpack(">II", png[16:24])
    assert width >= 1200 and height >= 1000  # a 4.2 × 4 inch panel at 300 dpi (was 110 dpi)
    assert b"pHYs" in png and struct.unpack(">I", png[png.index(b"pHYs") + 4:][:4])[0] == round(300 / 0.0254)


@pytest.mark.slow
def test_figure_formats_are_checked(result, tmp_path):
    with pytest.raises(ConfigError, match="allowed are png, svg, pdf"):
        write_report(result, tmp_path / "r", figure_formats=("png", "tiff"))
    files = write_report(result, tmp_path / "png-only", figure_formats=("png",))
    assert {p.suffix for p in files.figures} == {".png"}


def test_panel_letters_and_proportion_axis(result):
    from studyctl.analysis.plan import FigureEntry  # noqa: F401 - the spec type the drawers take
    from studyctl.report.compose import draw_figure
    from studyctl.report.figures import figure_bytes

    specs = {f.id: f for f in result.plan.figures}
    fig, _ = draw_figure(result, specs["prop"], None)
    ax = fig.axes[0]
    assert ax.get_ylim() == (0.0, 1.0)  # a proportion axis ends at 1
    fig, _ = draw_figure(result, specs["lik"], None)
    figure_bytes(fig, "svg")
    letters = [t.get_text() for ax in fig.axes for t in ax.texts if t.get_fontweight() == "bold"]
    assert letters == ["A", "B"]  # two items: two lettered panels
    assert fig.legends and [t.get_text() for t in fig.legends[0].get_texts()] == ["1", "2", "3", "4", "5"]


def test_summary_of_findings_leads_with_the_agreement_of_a_simulated_study(result):
    import dataclasses

    from studyctl.report.document import blocks

    agreement = pd.DataFrame({
        "role": ["fit", "fit", "validation", "validation"],
        "statistic": ["mean", "mean", "verdict", "mean"],
        "same_direction": [True, None, None, False],
        "same_verdict": [None, None, True, None],
        "within": [True, False, None, False],
        "agrees": [True, False, True, False],
        "sd_ratio": [np.nan] * 4,
    })
    sim = dataclasses.replace(result, tables={**result.tables, "agreement": agreement})
    (findings,) = [b for b in blocks(sim, [], []) if b[0] == "findings"]
    title, anchor, lines = findings[1][0]
    assert (title, anchor) == ("Simulated vs published", "simulated-vs-published")
    assert lines[0].startswith("2/4 (50%) published targets agree on every check")


def test_tables_tex_has_every_table_as_booktabs(written):
    tex = (written.out_dir / "tables.tex").read_text()
    html = written.html.read_text()
    assert tex.count("\\begin{table}") == tex.count("\\end{table}") == html.count("<table>")
    assert "\\toprule" in tex and "\\caption{kw}" in tex and "\\label{tab:kw}" in tex
    assert "\\textless{} .001" in tex  # p as printed, special characters escaped
    body = tex.split("\\begin{table}", 1)[1]
    assert "_" not in body.replace("\\_", "")  # every underscore escaped


@pytest.mark.slow
def test_effect_sizes_get_seeded_bootstrap_intervals(result):
    import dataclasses

    from studyctl.analysis.effect_ci import effect_size_intervals
    from studyctl.report.document import blocks

    ci = effect_size_intervals(result, replicates=300)
    assert list(ci["test_id"]) == ["groups", "groups", "groups", "kw"]  # rank-sum per condition, Kruskal-Wallis
    assert ((ci["ci_low"] <= ci["effect_size"]) & (ci["effect_size"] <= ci["ci_high"])).all()
    assert (ci["ci_low"] < ci["ci_high"]).all() and (ci["replicates"] == 300).all()
    pd.testing.assert_frame_equal(ci, effect_size_intervals(result, replicates=300))  # seeded: same intervals
    other = effect_size_intervals(result, replicates=300, seed=21)
    assert not np.allclose(other["ci_low"], ci["ci_low"])
    sim = dataclasses.replace(result, tables={**result.tables, "effect_sizes": ci})
    content = blocks(sim, [], [])
    (findings,) = [b for b in content if b[0] == "findings"]
    kw_line = next(lines for title, _, lines in findings[1] if title == "kw")[0]
    assert kw_line.startswith("Completion time: H(2) = ") and "ε² = .53 [." in kw_line
    methods = " ".join(b[1] for b in content if b[0] == "p")
    assert "percentile-bootstrap intervals (300 resamples, seeded generator, seed 20" in methods


def test_headlines_of_pairwise_only_entries_and_of_intervals(result):
    from studyctl.report.document import headline_lines

    se = next(e for e in result.plan.tests if e.id == "se")
    (line,) = headline_lines(se, result)
    assert line.startswith("3 intervals; lowest Sensitivity, ") and "highest Sensitivity, " in line
    row = {"kind": "pairwise", "statistic_name": "W = min(R+, R-)", "statistic": 0.0, "df": 20.0,
           "critical_value": 52.0, "p": 1.9e-6, "p_adjust": "none"}
    from studyctl.report import apa

    assert apa.line(row) == "W = 0, W_crit = 52, n = 20, p < .001"


def test_tables_of_values_name_the_unit(written):
    """Means, SDs and medians of a metric with a unit say it (a new user read '35.4' without knowing s or ms)."""
    import re

    rows = re.findall(r"<tr><td>(.*?)</td>", written.html.read_text())
    assert "Completion time (s)" in rows  # descriptives per condition and group
    assert "Sensitivity" in rows  # a proportion has no unit: no empty "()"
    assert not [r for r in rows if r.endswith("()")]


def test_agreement_table_names_the_unit_of_values_in_it():
    from studyctl.report.calibration import agreement_table

    base = {"role": "fit", "where": "", "published": 29.1, "published_low": 24.2, "published_high": 34.1,
            "band": "", "simulated": 35.4, "simulated_low": 17.6, "simulated_high": 53.3, "same_direction": None,
            "within": False, "same_verdict": None, "agrees": False, "sd_ratio": float("nan"), "note": ""}
    frame = pd.DataFrame([{**base, "target": "t_mean", "metric": "time", "statistic": "mean"},
                          {**base, "target": "t_pct", "metric": "time", "statistic": "pct_change_vs_baseline"},
                          {**base, "target": "f_prop", "metric": "found", "statistic": "proportion"}])
    head, body = agreement_table(frame, {"time": "s", "found": ""})
    compared = {row[0]: row[head.index("compared")] for row in body}
    assert compared == {"t_mean": "time (s), all: mean", "t_pct": "time, all: pct_change_vs_baseline",
                        "f_prop": "found, all: proportion"}  # a % change is not in seconds
    published = body[0][head.index("published (band)")]
    assert published == "29.1 [24.2, 34.1]"  # the value and its band share a cell


def test_agreement_table_fits_a_report_page_with_the_checks_in_view():
    """With fourteen columns the checks (within band, same verdict, agrees) were scrolled out of a report's width;
    every column but the checks now holds several fields, and a long verdict note stays in one cell."""
    from studyctl.report.calibration import agreement_table

    row = {"target": "newcombe_se_manual_PHF_verdict", "role": "validation", "metric": "sensitivity",
           "where": "pair=manual vs PHF", "statistic": "verdict", "published": True, "published_low": None,
           "published_high": None, "band": "verdict and direction (manual > PHF)", "simulated": True,
           "simulated_low": None, "simulated_high": None, "same_direction": True, "within": None,
           "same_verdict": True, "agrees": True, "sd_ratio": float("nan"), "replication": 0.92,
           "note": "margin (CI towards 0) = 0.164; manual higher"}
    head, body = agreement_table(pd.DataFrame([row]))
    assert len(head) == len(body[0]) == 10
    assert head[-5:] == ["same direction", "within band", "same verdict", "replication", "agrees"]
    cells = dict(zip(head, body[0], strict=True))
    assert cells["published (band)"] == "significant; verdict and direction (manual > PHF)"
    assert cells["simulated (95% interval)"] == "significant (margin (CI towards 0) = 0.164; manual higher)"
    assert (cells["same verdict"], cells["replication"], cells["within band"]) == ("yes", "92%", "")


def test_a_cell_with_no_condition_shows_an_empty_condition_not_nan(result):
    """An end-of-study questionnaire belongs to no condition: its row in the descriptives table had 'nan' there."""
    import dataclasses

    from studyctl.report.document import _cells_table

    cells = result.tables["cells"].copy()
    cells.loc[cells.index[0], "condition"] = np.nan
    head, body, _ = _cells_table(dataclasses.replace(result, tables={**result.tables, "cells": cells}))
    column = head.index("condition")
    assert body[0][column] == ""
    assert "nan" not in {str(cell) for row in body for cell in row}


@pytest.mark.parametrize("fmt", ["png", "svg", "pdf"])
def test_the_same_figure_saves_to_the_same_bytes_in_every_format(fmt):
    # matplotlib salts SVG element ids with a random uuid per save unless svg.hashsalt is set: two reports of the
    # same study differed in every SVG
    import matplotlib.pyplot as plt

    from studyctl.report.figures import figure_bytes

    fig, ax = plt.subplots()
    ax.plot([1, 2, 3], [3, 1, 2])
    ax.set_title("same figure")
    try:
        assert figure_bytes(fig, fmt) == figure_bytes(fig, fmt)
    finally:
        plt.close(fig)


def _laid_out_figure():
    """A constrained-layout figure whose layout moves things: two panels, long labels, a legend below."""
    from studyctl.report.figures import _figure, _legend_below

    fig, axes = _figure(2)
    for i, ax in enumerate(axes):
        (h,) = ax.plot([0, 1, 2], [i, 3, 1], label="series")
        ax.set_ylabel("a long label that pushes the panel right")
        ax.set_title(f"panel {i}")
    _legend_below(fig, [h], ["series"])
    fig.suptitle("short", fontsize=11)
    return fig


@pytest.mark.parametrize("fmt", ["png", "svg", "pdf"])
def test_a_save_lays_the_figure_out_once_and_draws_it_once(fmt, monkeypatch):
    # savefig with a layout engine draws the figure twice (a draw with rendering off only to run the layout, then the
    # real one); figure_bytes runs the engine itself and saves with it held off: one draw, the same bytes
    import io

    import matplotlib
    from matplotlib.figure import Figure

    from studyctl.report.figures import DPI, _panel_letters, figure_bytes

    meta = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}[fmt]
    plain = _laid_out_figure()
    _panel_letters(plain)  # what figure_bytes adds before saving
    buf = io.BytesIO()
    for _ in range(2):  # as the report does (one save per format), positions carry over from save to save
        buf = io.BytesIO()
        with matplotlib.rc_context({"svg.hashsalt": "studyctl"}):
            plain.savefig(buf, format=fmt, dpi=DPI, metadata=meta)
    fig = _laid_out_figure()
    figure_bytes(fig, fmt)
    draws = []
    draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: (draws.append(1), draw(self, renderer))[1])
    assert figure_bytes(fig, fmt) == buf.getvalue()
    assert len(draws) == 1
    assert fig.get_layout_engine() is not None and type(fig.get_layout_engine()).__name__ == "ConstrainedLayoutEngine"
    assert [ax.get_position().bounds for ax in fig.axes] == [ax.get_position().bounds for ax in plain.axes]


def test_methods_name_a_models_second_factor_not_the_plan_key():
    """The aligned-rank-transform paragraph of seed 000's report read 'of the compared factor × options.factor':
    a plan key, not the study's factor."""
    from pathlib import Path
    from types import SimpleNamespace

    from studyctl.report.findings import methods_text

    plan = load_plan(Path(__file__).parents[2] / "analysis" / "bio_inspired_palpation.yaml")
    paras = methods_text(SimpleNamespace(plan=plan, tables={}))
    art = next(p for p in paras if "aligned rank transform" in p)
    assert "options.factor" not in " ".join(paras)
    assert "comparing the levels of condition crossed with group" in art
