"""The one HTML report writer: header, escaped tables, embedded figures, atomic write."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ebus_env.html_report import Figure, Section, Table, write_report  # noqa: E402


def test_report_has_header_escaped_tables_and_figures(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    path = write_report(
        tmp_path / "r.html", "A <study>", [
            Section("Costs", "cheapest first", [Table(["option", "cost/km"], [["T1<x>", 0.5]])],
                    [Figure.of(fig, "pareto", "Pareto front")], link=("other.html", "more"))],
        ran="ebus study example.yaml", settings={"days": 2}, how_to_read="lower is better")
    page = path.read_text()
    assert "<h1>A &lt;study&gt;</h1>" in page and "<td>T1&lt;x&gt;</td>" in page
    assert "What was run</dt><dd>ebus study example.yaml" in page and "days: 2" in page
    assert page.count('src="data:image/png;base64,') == 1 and 'id="plot-pareto"' in page
    assert 'data-plots-rendered="0/1"' in page and '<a href="other.html">more</a>' in page
    assert [p.name for p in tmp_path.iterdir()] == ["r.html"]  # no temporary file left
