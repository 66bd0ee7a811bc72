"""Small HTML building blocks for the report: one self-contained page, no script.

Everything is inline (CSS in a ``<style>`` element, figures as base64 PNG
``data:`` URIs), so the file opens anywhere without a network and can be mailed
as one attachment. Every text goes through :func:`esc`.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Sequence
from typing import Any

CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 1.5em auto;
       max-width: 1150px; color: #222; line-height: 1.35; padding: 0 1em; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; margin-top: 1.8em;
     border-bottom: 1px solid #ccc; padding-bottom: 0.2em; } h3 { font-size: 1.0em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.85em; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.55em; text-align: right; white-space: nowrap; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
tr.dim td { color: #999; }
.box { border: 1px solid #bbb; border-radius: 4px; padding: 0.6em 1em; margin: 1em 0; background: #fafafa; }
.ok { color: #17692b; font-weight: bold; } .bad { color: #b00020; font-weight: bold; }
.warn { color: #8a5a00; font-weight: bold; }
figure { margin: 0.8em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: 0.85em; color: #555; }
.small { font-size: 0.85em; color: #555; } code { background: #f3f3f3; padding: 0 0.2em; }
"""


def esc(text: Any) -> str:
    return html.escape(str(text), quote=True)


def fmt(value: float | None, digits: int = 4) -> str:
    """A number for a table cell: ``digits`` significant figures, blank for None or NaN."""
    if value is None or not math.isfinite(value):
        return ""
    return f"{value:.{digits}g}"


def fixed(value: float | None, decimals: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return ""
    return f"{value:.{decimals}f}"


def table(
    header: Sequence[str],
    rows: Iterable[Sequence[Any]],
    left: int = 1,
    dim: Sequence[bool] | None = None,
) -> str:
    """A table; the first ``left`` columns are left-aligned; cells are escaped; ``dim`` greys rows."""
    out = ["<table><tr>"]
    out += [f'<th class="{"l" if i < left else ""}">{esc(h)}</th>' for i, h in enumerate(header)]
    out.append("</tr>")
    for r, row in enumerate(rows):
        cls = ' class="dim"' if dim is not None and dim[r] else ""
        out.append(f"<tr{cls}>")
        out += [f'<td class="{"l" if i < left else ""}">{esc(c)}</td>' for i, c in enumerate(row)]
        out.append("</tr>")
    out.append("</table>")
    return "".join(out)


def image(name: str, png: bytes, caption: str) -> str:
    """A figure with its PNG inline (``data:`` URI) and a caption."""
    data = base64.b64encode(png).decode("ascii")
    return (
        f'<figure id="fig-{esc(name)}"><img alt="{esc(caption)}" '
        f'src="data:image/png;base64,{data}"><figcaption>{esc(caption)}</figcaption></figure>'
    )


def verdict(passed: bool | None, text: str) -> str:
    cls = {True: "ok", False: "bad", None: "warn"}[passed]
    word = {True: "PASS", False: "FAIL", None: "NOT JUDGED"}[passed]
    return f'<p><span class="{cls}">{word}</span> {esc(text)}</p>'


def page(title: str, body: Sequence[str]) -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title><style>{CSS}</style></head><body>\n"
        + "\n".join(body)
        + "\n</body></html>\n"
    )


def flatten(prefix: str, value: Any) -> list[tuple[str, str]]:
    """Nested settings as ``(dotted.key, value)`` rows."""
    if isinstance(value, dict):
        rows: list[tuple[str, str]] = []
        for k, v in value.items():
            rows += flatten(f"{prefix}.{k}" if prefix else str(k), v)
        return rows
    if isinstance(value, float):
        return [(prefix, f"{value:.6g}")]
    return [(prefix, str(value))]
