"""One writer for every HTML report (demo, diagnosis, fleet study).

A report is a header (what was run, with which settings, how to read it), an optional verdict,
and sections of text, tables and figures. Figures are embedded as base64 PNG, so the file opens
offline; the page is rendered from the package template ``templates/report.html.j2`` (jinja2,
autoescaped) and written to a temporary file in the target folder, then renamed.
"""

from __future__ import annotations

import base64
import io
from dataclasses import dataclass, field
from pathlib import Path

from ebus_env.outputs import write_text


@dataclass
class Figure:
    """An embedded PNG figure; ``name`` becomes the image id ``plot-<name>``."""

    name: str
    alt: str
    png: str

    @classmethod
    def of(cls, fig, name: str, alt: str = "", dpi: int = 100) -> Figure:
        """Render a matplotlib figure to PNG and close it."""
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        plt.close(fig)
        return cls(name, alt or name, base64.b64encode(buf.getvalue()).decode("ascii"))


@dataclass
class Table:
    """A table of already formatted cells."""

    header: list[str]
    rows: list[list]
    title: str = ""


@dataclass
class Section:
    """A titled part of a report: a paragraph (with an optional ``(href, label)`` link),
    figures, then tables."""

    title: str
    text: str = ""
    tables: list[Table] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    link: tuple[str, str] | None = None


def render(title: str, sections: list[Section], *, ran: str = "", settings: dict | None = None,
           how_to_read: str = "", verdict: str = "", verdict_found: bool = True) -> str:
    """The report page as a string."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("ebus_env", "templates"),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True)
    n_figures = sum(len(s.figures) for s in sections)
    return env.get_template("report.html.j2").render(
        title=title, sections=sections, ran=ran, settings=settings or {},
        how_to_read=how_to_read, verdict=verdict, verdict_found=verdict_found,
        n_figures=n_figures)


def write_report(path: str | Path, title: str, sections: list[Section], **header) -> Path:
    """Render the report (see :func:`render` for the header fields) and write it atomically."""
    return write_text(path, render(title, sections, **header))
