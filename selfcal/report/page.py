"""HTML building blocks of the report: one self-contained page, readable offline and printable.

Figures are embedded as PNG data URIs (the page needs no other file) and link
to their SVG beside it in ``figures/``. Every number taken from summary.json is
printed in an element that names its key (``data-summary``) and holds the exact
value (``data-value``), so that a reader, or a test, can check one against the other.
"""
from __future__ import annotations

import base64
import html
import math

__all__ = ["Page", "fmt", "summary_cell"]

_CSS = """
body { font-family: "DejaVu Sans", Helvetica, Arial, sans-serif; font-size: 10.5pt; color: #222;
       max-width: 60em; margin: 1.5em auto; padding: 0 1em; line-height: 1.35; }
h1 { font-size: 17pt; margin-bottom: 0.2em; } h2 { font-size: 13pt; border-bottom: 1px solid #bbb;
     margin-top: 1.6em; } h3 { font-size: 11pt; margin-bottom: 0.3em; }
.lede { color: #555; margin-top: 0; }
table { border-collapse: collapse; margin: 0.4em 0 1em; font-size: 9pt; }
th, td { border-bottom: 1px solid #ddd; padding: 2px 8px; text-align: right; white-space: nowrap; }
th { background: #f2f2f2; } td.text, th.text { text-align: left; }
tr.flag td { background: #fde8e8; }
figure { margin: 0.6em 0 1.4em; page-break-inside: avoid; break-inside: avoid; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 9pt; color: #444; }
.note { font-size: 9pt; color: #555; }
.bad { color: #b00; font-weight: bold; }
details { margin: 0.3em 0 1em; } details > summary { cursor: pointer; color: #235; font-size: 9pt; }
@media print { body { max-width: none; margin: 0; font-size: 9.5pt; } h2 { page-break-after: avoid; }
               table { page-break-inside: auto; } tr { page-break-inside: avoid; } a { color: inherit; } }
"""

# Counts the page's images that failed to load, so that a browser (or a test) can see it.
_IMAGE_CHECK = """
window.addEventListener("load", function () {
  var images = document.images, broken = 0;
  for (var i = 0; i < images.length; i++) {
    if (!images[i].complete || images[i].naturalWidth === 0) { broken++; }
  }
  document.body.setAttribute("data-images", images.length);
  document.body.setAttribute("data-broken-images", broken);
});
"""


def fmt(value: object, spec: str = ".4f") -> str:
    """A number as text; empty for None/NaN, integers and booleans as they are."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, bool) or isinstance(value, str):
        return str(value)
    if isinstance(value, int) and not spec.endswith("e"):
        return str(value)
    return format(value, spec)


def summary_cell(summary: dict, key: str, spec: str = ".4f") -> str:
    """A table cell with the value of ``summary[key]`` (dotted keys reach into nested dicts)."""
    value: object = summary
    for part in key.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    exact = "" if value is None else html.escape(repr(value), quote=True)
    return f'<td data-summary="{html.escape(key)}" data-value="{exact}">{html.escape(fmt(value, spec))}</td>'


class Page:
    """An HTML page assembled section by section."""

    def __init__(self, title: str):
        self.title = title
        self.parts: list[str] = []

    def add(self, markup: str) -> None:
        self.parts.append(markup)

    def heading(self, text: str, level: int = 2, anchor: str | None = None) -> None:
        ident = f' id="{html.escape(anchor)}"' if anchor else ""
        self.add(f"<h{level}{ident}>{html.escape(text)}</h{level}>")

    def paragraph(self, text: str, css: str | None = None) -> None:
        cls = f' class="{css}"' if css else ""
        self.add(f"<p{cls}>{html.escape(text)}</p>")

    def figure(self, png: bytes, svg_name: str | None, caption: str, alt: str) -> None:
        data = base64.b64encode(png).decode("ascii")
        link = f' <a href="{html.escape(svg_name)}">SVG</a>' if svg_name else ""
        self.add(f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(alt)}">'
                 f"<figcaption>{html.escape(caption)}{link}</figcaption></figure>")

    def table(self, header: list[str], rows: list[list], text_columns: int | set[int] = 1,
              flagged: list[bool] | None = None, ident: str | None = None) -> None:
        """A table; columns of text align left (the first ``text_columns``, or those in the set)."""
        left = set(range(text_columns)) if isinstance(text_columns, int) else set(text_columns)

        def cell(j, value, tag):
            css = ' class="text"' if j in left else ""
            return f"<{tag}{css}>{html.escape(str(value))}</{tag}>"
        out = [f'<table id="{html.escape(ident)}">' if ident else "<table>"]
        out += ["<thead><tr>" + "".join(cell(j, h, "th") for j, h in enumerate(header)) + "</tr></thead><tbody>"]
        for i, row in enumerate(rows):
            css = ' class="flag"' if flagged and flagged[i] else ""
            out.append(f"<tr{css}>" + "".join(cell(j, v, "td") for j, v in enumerate(row)) + "</tr>")
        out.append("</tbody></table>")
        self.add("".join(out))

    def html(self) -> str:
        body = "\n".join(self.parts)
        return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
                f'<meta name="viewport" content="width=device-width, initial-scale=1">'
                f"<title>{html.escape(self.title)}</title><style>{_CSS}</style>"
                f"<script>{_IMAGE_CHECK}</script></head>\n<body>\n{body}\n</body></html>\n")
