"""Small HTML building blocks: escaping, numbers, tables, embedded figures, CSS.

Every piece of text that comes from a file goes through :func:`esc`; functions that return
markup return :class:`Raw` so tables know not to escape it again.
"""

from __future__ import annotations

import base64
import hashlib
import html
import io
import math
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path


class Raw(str):
    """A string that is already HTML (not escaped again by :func:`cell`)."""


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def num(x, digits: int = 4) -> Raw:
    """A number for a table: ``—`` for None/NaN, ``digits`` significant digits, powers of
    ten as ``1.2 × 10⁻⁵`` (HTML ``<sup>``)."""
    if x is None:
        return Raw('<span class="na">—</span>')
    if isinstance(x, bool):
        return Raw("yes" if x else "no")
    if isinstance(x, int):
        return Raw(f"{x:,}".replace(",", "\u2009"))
    try:
        v = float(x)
    except (TypeError, ValueError):
        return Raw(esc(x))
    if math.isnan(v):
        return Raw('<span class="na">—</span>')
    if math.isinf(v):
        return Raw("∞" if v > 0 else "−∞")
    if v == 0:
        return Raw("0")
    if 1e-3 <= abs(v) < 1e6:
        s = f"{v:.{digits}g}"
        if "e" in s:  # 2712 rather than 2.71 × 10³
            s = f"{v:.0f}"
        return Raw(s.replace("-", "−"))
    m, e = f"{v:.{max(digits - 1, 0)}e}".split("e")
    m = m.rstrip("0").rstrip(".") if "." in m else m
    return Raw(f"{m.replace('-', '−')}\u202f×\u202f10<sup>{str(int(e)).replace('-', '−')}</sup>")


def digits(text: str) -> Raw:
    """A number already written with its digits (``rotorbayes.util.numformat``: ``4.3687027``,
    ``4.8e-06``) as a table shows numbers: a true minus, powers of ten as ``4.8 × 10⁻⁶``."""
    mant, e, exp = str(text).partition("e")
    out = esc(mant).replace("-", "−")
    if e:
        out += f"\u202f×\u202f10<sup>{str(int(exp)).replace('-', '−')}</sup>"
    return Raw(out)


def pval(p) -> Raw:
    """A p-value: two significant digits, ``< 10⁻¹⁶`` below machine precision."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return num(None)
    if p < 1e-16:
        return Raw("&lt;\u202f10<sup>−16</sup>")
    return num(p, 2)


def cell(v) -> str:
    if isinstance(v, Raw):
        return str(v)
    if v is None or isinstance(v, int | float):
        return str(num(v))
    return esc(v)


def table(
    headers, rows, *, cls: str = "", numeric: tuple[int, ...] = (), caption: str = "", row_cls=None
) -> Raw:
    """An HTML table; ``numeric`` column indices are right-aligned; ``row_cls(i)`` may give a
    class per row."""
    nc, nw = ' class="n"', ' class="nw"'
    # A unit column never breaks a unit ("N m s/rad") over lines.
    nowrap = {i for i, h in enumerate(headers) if str(h).strip().lower() == "unit"}
    head = "".join(f"<th{nc if i in numeric else ''}>{cell(h)}</th>" for i, h in enumerate(headers))
    body = []
    for k, r in enumerate(rows):
        rc = row_cls(k) if row_cls else ""
        tds = "".join(
            f"<td{nc if i in numeric else nw if i in nowrap else ''}>{cell(v)}</td>"
            for i, v in enumerate(r)
        )
        rattr = f' class="{esc(rc)}"' if rc else ""
        body.append(f"<tr{rattr}>{tds}</tr>")
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    return Raw(
        f'<div class="tw"><table class="{esc(cls)}">{cap}<thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table></div>"
    )


def kv(pairs) -> Raw:
    """A two-column table of labels and values."""
    rows = "".join(f"<tr><th>{esc(k)}</th><td>{cell(v)}</td></tr>" for k, v in pairs)
    return Raw(f'<div class="tw"><table class="kv"><tbody>{rows}</tbody></table></div>')


def ul(items, cls: str = "") -> Raw:
    if not items:
        return Raw("")
    li = "".join(f"<li>{cell(i)}</li>" for i in items)
    return Raw(f'<ul class="{esc(cls)}">{li}</ul>')


def pre(text: str) -> Raw:
    return Raw(f"<pre>{esc(text)}</pre>")


MIME = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml",
    ".gif": "image/gif",
    ".webp": "image/webp",
}


def compact_png(data: bytes) -> bytes:
    """A PNG re-encoded with a 256-colour palette (no dithering) when that is smaller: the
    figures are line art, for which this looks the same at a third of the size. The original
    bytes if Pillow is missing or the image cannot be read."""
    try:
        from PIL import Image
    except ImportError:
        return data
    try:
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            if im.mode in ("RGBA", "LA") or (im.mode == "P" and "transparency" in im.info):
                rgba = im.convert("RGBA")
                im = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
                im.alpha_composite(rgba)
            q = im.convert("RGB").quantize(
                256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE
            )
            buf = io.BytesIO()
            q.save(buf, "PNG", optimize=True)
    except Exception:  # noqa: BLE001 - an odd image is embedded as it is
        return data
    out = buf.getvalue()
    return out if len(out) < len(data) else data


@dataclass
class FigureStore:
    """The figures embedded so far: identical files are embedded once (later ones link to
    the first); ``compact`` re-encodes PNGs with :func:`compact_png`."""

    compact: bool = True
    seen: dict = field(default_factory=dict)  # sha256 -> (anchor id, caption)
    count: int = 0
    raw_bytes: int = 0
    embedded_bytes: int = 0


_STORE: ContextVar[FigureStore | None] = ContextVar("rotorbayes_report_figures", default=None)


@contextmanager
def figure_store(compact: bool = True):
    """Collect the figures of one page (see :class:`FigureStore`)."""
    store = FigureStore(compact)
    token = _STORE.set(store)
    try:
        yield store
    finally:
        _STORE.reset(token)


def figure(path: Path, caption: str) -> Raw:
    """``path`` embedded as a data URI with its caption, or a note that it is missing."""
    if not path.exists():
        return Raw(f'<p class="note">Figure {esc(path.name)} is not in {esc(path.parent)}/.</p>')
    store = _STORE.get() or FigureStore(compact=False)
    data = path.read_bytes()
    key = hashlib.sha256(data).hexdigest()
    if key in store.seen:
        anchor, first = store.seen[key]
        return Raw(
            f'<p class="note">{esc(caption)} ({esc(path.name)}): the same figure as '
            f'<a href="#{anchor}">{esc(first)}</a> above.</p>'
        )
    store.count += 1
    anchor = f"fig-{store.count}"
    size = png_size(data)
    store.seen[key] = (anchor, caption)
    mime = MIME.get(path.suffix.lower(), "application/octet-stream")
    store.raw_bytes += len(data)
    if store.compact and mime == "image/png":
        data = compact_png(data)
    store.embedded_bytes += len(data)
    b64 = base64.b64encode(data).decode("ascii")
    dims = f' width="{size[0]}" height="{size[1]}"' if size else ""
    wide = ' class="wide"' if size is None or size[0] >= WIDE_PX else ""
    return Raw(
        f'<figure id="{anchor}"{wide}><img src="data:{mime};base64,{b64}"{dims} '
        f'alt="{esc(caption)}" title="{esc(path.name)}"><figcaption>{esc(caption)} '
        f'<span class="file">({esc(path.name)})</span></figcaption></figure>'
    )


#: Figures at least this wide (pixels) take the whole width of the page; narrower ones may
#: stand side by side.
WIDE_PX = 900


def png_size(data: bytes) -> tuple[int, int] | None:
    """Width and height from a PNG's header, None for anything else."""
    if len(data) >= 24 and data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    return None


def markdown_table(text: str) -> Raw | None:
    """A Markdown pipe table (as ``rotorbayes sample`` writes summary.md) as HTML; None if the
    text holds none."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith("|")]
    if len(lines) < 2:
        return None

    def cells(ln: str) -> list[str]:
        return [c.strip() for c in ln.strip().strip("|").split("|")]

    head = cells(lines[0])
    body = [cells(ln) for ln in lines[1:] if not set(ln.replace("|", "").strip()) <= set("-: ")]
    numeric = tuple(
        i for i in range(len(head)) if body and all(_numberish(r[i]) for r in body if i < len(r))
    )
    return table(head, body, numeric=numeric, cls="md")


def _numberish(s: str) -> bool:
    s = s.strip("[]() ")
    try:
        float(s.split(",")[0])
        return True
    except ValueError:
        return False


CSS = """
:root{--fg:#1d232b;--muted:#5b6573;--line:#d8dde3;--bg:#fff;--soft:#f4f6f8;--accent:#1f5fa8;
--good:#1d7a3a;--goodbg:#e8f5ec;--bad:#a33a16;--badbg:#fcefe9;--warnbg:#fff6dc}
*{box-sizing:border-box}
html{scroll-behavior:smooth}
body{margin:0;color:var(--fg);background:var(--bg);font:15px/1.5 system-ui,-apple-system,
"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif}
main{max-width:1220px;margin:0 auto;padding:24px 28px 64px}
header.top{border-bottom:3px solid var(--accent);margin-bottom:18px;padding-bottom:10px}
h1{font-size:26px;margin:0 0 4px}
h2{font-size:21px;margin:0 0 10px;padding-bottom:4px;border-bottom:1px solid var(--line)}
h3{font-size:16.5px;margin:20px 0 6px}
h4{font-size:15px;margin:14px 0 4px}
.sub{color:var(--muted);margin:0}
section{margin:30px 0;scroll-margin-top:12px}
nav.toc{background:var(--soft);border:1px solid var(--line);border-radius:6px;padding:10px 16px;
margin:12px 0 6px}
nav.toc ol{margin:4px 0;padding-left:22px;columns:2;column-gap:32px}
nav.toc li{margin:1px 0}
nav.toc .absent-list{color:var(--muted);font-size:13.5px;margin:8px 0 0;border-top:1px solid
var(--line);padding-top:6px}
nav.toc .absent-list ul{margin:2px 0;padding-left:22px}
a{color:var(--accent);text-decoration:none}
a:hover{text-decoration:underline}
.verdict{border-radius:6px;padding:12px 18px;border:1px solid var(--line);background:var(--soft)}
.verdict.good{background:var(--goodbg);border-color:#9fd0ad}
.verdict.bad{background:var(--badbg);border-color:#ecb9a5}
.verdict .headline{font-size:18px;font-weight:600;margin:0 0 6px}
.verdict ul{margin:6px 0 0;padding-left:20px}
.tag{display:inline-block;border-radius:4px;padding:0 7px;font-size:12.5px;font-weight:600;
vertical-align:1px}
.tag.good{background:var(--goodbg);color:var(--good);border:1px solid #9fd0ad}
.tag.bad{background:var(--badbg);color:var(--bad);border:1px solid #ecb9a5}
.tag.muted{background:var(--soft);color:var(--muted);border:1px solid var(--line)}
.tw{overflow-x:auto;margin:8px 0 12px}
table{border-collapse:collapse;font-size:13.5px;min-width:40%}
caption{text-align:left;color:var(--muted);font-size:13px;padding:2px 0 4px}
th,td{border-bottom:1px solid var(--line);padding:4px 10px;text-align:left;vertical-align:top}
thead th{background:var(--soft);border-bottom:2px solid var(--line);white-space:nowrap}
tbody tr:nth-child(even){background:#fafbfc}
td.n,th.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
table.kv th{background:none;font-weight:600;white-space:nowrap;color:var(--muted);width:1%}
table.grouped tbody tr.grp-a td{background:#fff}
table.grouped tbody tr.grp-b td{background:#f4f6f8}
tr.good td{background:var(--goodbg)}
tr.bad td{background:var(--badbg)}
tr.muted td{color:var(--muted)}
.na{color:var(--muted)}
code,pre,.mono{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,"DejaVu Sans Mono",
monospace;font-size:12.5px}
pre{background:var(--soft);border:1px solid var(--line);border-radius:5px;padding:10px 12px;
overflow-x:auto;white-space:pre-wrap;word-break:break-word}
.hash{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:11.5px;word-break:break-all}
.path{font-size:12px;color:var(--muted);overflow-wrap:anywhere}
.small{font-size:12.5px;color:var(--muted)}
.nw{white-space:nowrap}
figure{margin:14px 0;text-align:center}
figure img{max-width:100%;max-height:1150px;width:auto;height:auto;border:1px solid var(--line);
border-radius:4px}
.figs figure.wide{grid-column:1/-1}
figcaption{font-size:13px;color:var(--muted);margin-top:4px}
figcaption .file{font-size:12px}
.figs{display:grid;grid-template-columns:repeat(auto-fit,minmax(440px,1fr));gap:8px 18px;
align-items:start}
.note{color:var(--muted);font-size:14px}
.warn{background:var(--warnbg);border:1px solid #ecd588;border-radius:5px;padding:8px 14px;
margin:8px 0}
.warn ul{margin:2px 0;padding-left:18px}
.advice{border-left:4px solid var(--accent);background:var(--soft);padding:8px 14px;margin:8px 0;
white-space:pre-wrap}
details{margin:8px 0}
summary{cursor:pointer;color:var(--accent)}
.absent{color:var(--muted)}
footer{margin-top:40px;border-top:1px solid var(--line);padding-top:8px;color:var(--muted);
font-size:12.5px}
@media print{nav.toc{display:none}section{break-inside:avoid-page}}
@media (max-width:700px){nav.toc ol{columns:1}.figs{grid-template-columns:1fr}}
"""
