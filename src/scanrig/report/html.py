"""HTML assembly for the report: one page, inline CSS, escaped text, no external resource.

The page has a Content-Security-Policy that forbids any network access (images only from
``data:`` URIs, scripts and styles only inline), so a browser that opens it never reaches out.
"""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, field

#: Forbid every fetch; allow the inline script and style and data: images the page carries.
CSP = ("default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'; "
       "connect-src 'none'; form-action 'none'; base-uri 'none'")

_STYLE = """
* { box-sizing: border-box; }
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1500px; padding: 0 24px 48px;
       color: #222; background: #fafafa; overflow-wrap: anywhere; }
h1 { margin: 12px 0 4px; font-size: 24px; } h2 { border-bottom: 2px solid #ccc; padding-bottom: 4px; margin-top: 36px; }
section#verdict h2 { margin: 4px 0 8px; font-size: 20px; }
table { border-collapse: collapse; margin: 8px 0 16px; font-size: 14px; display: block; max-width: 100%;
        overflow-x: auto; }
th, td { border: 1px solid #ccc; padding: 3px 10px; text-align: right; }
th { background: #eee; } td.text, th.text { text-align: left; }
img { max-width: 100%; display: block; margin: 8px 0; }
pre { background: #f0f0f0; padding: 8px; white-space: pre-wrap; font-size: 13px; max-width: 100%; }
.note { color: #666; font-style: italic; }
.first-screen { display: flex; flex-wrap: wrap; gap: 20px; align-items: flex-start; }
.first-view { flex: 0 1 802px; min-width: 0; } .first-view p { margin: 2px 0; }
.verdict { flex: 1 1 300px; margin: 0; font-size: 15px; }
.verdict dt { font-weight: 600; margin-top: 8px; } .verdict dd { margin: 2px 0 0 0; }
.viewer canvas { background: #202020; border: 1px solid #999; max-width: 100%; }
.viewer-bar { display: flex; flex-wrap: wrap; gap: 8px 20px; align-items: center; margin: 6px 0; }
.viewer-bar canvas { background: none; border: none; }
.hint { color: #666; font-size: 13px; }
.gallery { display: flex; flex-wrap: wrap; gap: 12px; }
.gallery figure { margin: 0; max-width: 100%; } .gallery figcaption { font-size: 13px; color: #444; }
"""


@dataclass
class Section:
    """One ``<section>``: a title and HTML body fragments, in order."""

    title: str
    parts: list[str] = field(default_factory=list)

    @property
    def anchor(self) -> str:
        """The section's id: its title in lower case, words joined by ``-`` (``#point-cloud``)."""
        return re.sub(r"[^a-z0-9]+", "-", self.title.lower()).strip("-")

    def text(self, words: str, css: str = "") -> None:
        cls = f' class="{css}"' if css else ""
        self.parts.append(f"<p{cls}>{html.escape(words)}</p>")

    def note(self, words: str) -> None:
        self.text(words, "note")

    def pre(self, text: str) -> None:
        """Preformatted text (e.g. a summary file)."""
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def image(self, uri: str, alt: str) -> None:
        self.parts.append(f'<img src="{uri}" alt="{html.escape(alt)}">')

    def gallery(self, items: list[tuple[str, str]]) -> None:
        """Images side by side: ``(data URI, caption)`` each."""
        figs = "".join(f'<figure><img src="{u}" alt="{html.escape(c)}">'
                       f'<figcaption>{html.escape(c)}</figcaption></figure>' for u, c in items)
        self.parts.append(f'<div class="gallery">{figs}</div>')

    def table(self, header: list[str], rows: list[list]) -> None:
        self.parts.append(table_html(header, rows))

    def raw(self, fragment: str) -> None:
        """Trusted HTML built by this package (e.g. the viewer)."""
        self.parts.append(fragment)


def _cell(value, tag: str) -> str:
    text = fmt(value)
    css = ' class="text"' if isinstance(value, str) else ""
    return f"<{tag}{css}>{html.escape(text)}</{tag}>"


def fmt(value) -> str:
    """A table cell: floats with 4 significant digits, others as ``str``."""
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def table_html(header: list[str], rows: list[list]) -> str:
    head = "".join(f'<th class="text">{html.escape(h)}</th>' for h in header)
    body = "".join("<tr>" + "".join(_cell(v, "td") for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def page(title: str, sections: list[Section]) -> str:
    """The whole document."""
    body = "".join(f'<section id="{s.anchor}"><h2>{html.escape(s.title)}</h2>{"".join(s.parts)}</section>'
                   for s in sections)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta http-equiv="Content-Security-Policy" content="{CSP}">'
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>"
            f"<body><h1>{html.escape(title)}</h1>{body}</body></html>\n")
