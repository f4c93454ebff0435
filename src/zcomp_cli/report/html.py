"""The page of ``zcomp report``: one self-contained HTML file.

Inline CSS and JavaScript, no external resource (a Content-Security-Policy forbids any:
images come from relative links only; the one script runs by its nonce, no inline event
handler), so it works from ``file://``. The template's slots are filled in one pass
(``fill``: no value is searched for slots again). The rows travel as one JSON document in
a ``<script type="application/json">``, with every ``<``, ``>``, ``&`` and quote inside
a string written as a ``\\u`` escape so that no text (a job name holding
``</script>``) can end it; the script builds the table with DOM text nodes and
attributes, never HTML strings, so text is never markup. Sorting (every column; numbers
numerically, missing values last both ways), a status filter, a text filter and
pagination run in the browser: one page of rows is in the DOM at a time, so 10 000 jobs
open in a second.
"""

from __future__ import annotations

import datetime as _dt
import html
import json
import math
import re
import secrets

from zcomp_cli.limits import field_text
from zcomp_cli.report.collect import STATUS_ORDER, Collected, status_rank

METRIC_NAME_CHARS = 64  # a metric's name in a column's header (eval.json may hold any text)

# Metrics where higher is better (metrics.evaluate.HIGHER_IS_BETTER; copied so that the
# page does not import the metrics package).
_HIGHER_IS_BETTER = {"psnr", "ssim", "shadow-iou"}


def _jnum(v):
    """A number for the JSON blob: 6 significant digits, +-inf as "inf"/"-inf" (JSON
    has no infinity), None for NaN or no value."""
    if v is None or isinstance(v, bool):
        return None
    v = float(v)
    if math.isnan(v):
        return None
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return float(f"{v:.6g}")


def columns(col: Collected) -> list[dict]:
    """The table's columns: ``key`` (a row's field; ``m:<metric>`` for eval metrics),
    ``label``, ``type`` (img, text, status, num) and, for some, ``tip`` (the extra
    field shown as the cell's tooltip)."""
    cols = [
        {"key": "composite", "label": "composite", "type": "img"},
        {"key": "closeup", "label": "close-up", "type": "crop",
         "title": "the composite around the object and its shadow (the region the renderer re-shaded)"},
        {"key": "background", "label": "background", "type": "img"},
        {"key": "job", "label": "job", "type": "text"},
        {"key": "scene", "label": "scene", "type": "text"},
        {"key": "object", "label": "object", "type": "text"},
        {"key": "renderer", "label": "renderer", "type": "text"},
        {"key": "status", "label": "status", "type": "status"},
        {"key": "reason", "label": "failure reason", "type": "text", "wide": True},
        {"key": "light", "label": "light", "type": "text", "tip": "light_note", "wide": True},
    ]
    if any(r["light_uncertainty"] is not None for r in col.rows):
        cols.append({"key": "light_uncertainty", "label": "light ±°", "type": "num",
                     "title": "uncertainty of the light's direction (degrees, RMS)"})
    for m in col.metrics:
        better = "↑" if m in _HIGHER_IS_BETTER else "↓"
        shown = field_text(m, METRIC_NAME_CHARS)
        cols.append({"key": f"m:{m}", "label": f"{shown} {better}", "type": "num",
                     "title": f"{shown} ({'higher' if better == '↑' else 'lower'} is better), from zcomp eval"})
    cols.append({"key": "seconds", "label": "time s", "type": "num", "title": "seconds the job took"})
    return cols


EXTRA = ("light_note",)  # fields after the columns in each row array (tooltips)


def _cell(row: dict, key: str, urls: dict):
    if key in ("composite", "background"):
        return urls[key].get(row["job"])
    if key == "closeup":  # [url, x0, y0, x1, y1, W, H]: the page crops the composite itself
        url, box = urls["composite"].get(row["job"]), row.get("closeup")
        return [url, *box] if url and box else None
    if key.startswith("m:"):
        return _jnum(row["metrics"].get(key[2:]))
    v = row.get(key)
    if isinstance(v, str):  # (a failure reason of 100 MB, a name of undecodable bytes)
        return field_text(v)
    return _jnum(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v


def page_data(col: Collected, page_size: int, urls: dict) -> dict:
    """The JSON document the page's script reads."""
    cols = columns(col)
    rows = [[_cell(r, c["key"], urls) for c in cols] + [_cell(r, k, urls) for k in EXTRA] for r in col.rows]
    statuses = sorted({r["status"] for r in col.rows} | set(STATUS_ORDER), key=status_rank)
    return {"columns": cols, "extra": list(EXTRA), "rows": rows, "pageSize": int(page_size),
            "statuses": statuses}


def script_json(obj) -> str:
    """JSON safe inside ``<script>`` and anywhere else in the page: ``<``, ``>``, ``&``,
    the two JavaScript line separators and a quote inside a string (JSON's ``\\"``) as
    ``\\u`` escapes (they occur only inside JSON strings, where the escape means the
    same character), so no text of the data can end the element or an attribute."""
    s = json.dumps(obj, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    for ch, esc in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026"), ("\u2028", "\\u2028"),
                    ("\u2029", "\\u2029")):
        s = s.replace(ch, esc)
    # JSON's escapes, read pairwise from the left (so ``\\\\`` before a closing quote
    # stays a backslash): an escaped quote becomes \\u0022
    return _ESCAPE.sub(lambda m: "\\u0022" if m.group(0) == '\\"' else m.group(0), s)


_ESCAPE = re.compile(r"\\.", re.S)


def _fmt(v) -> str:
    if v is None:
        return "n/a"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"


def render_page(col: Collected, *, title: str, page_size: int, urls: dict, url_of, version: str = "") -> str:
    """The whole page. ``urls``: {"composite": {job: url}, "background": {job: url}};
    ``url_of(path)``: the page-relative URL of a file (preview sheets, eval file)."""
    e = html.escape
    counts = col.counts
    total = len(col.rows)
    count_text = ", ".join(f"{n} {s}" for s, n in counts.items()) or "no jobs"
    head = [f'<p class="meta"><span id="total">{total}</span> job{"s" if total != 1 else ""}: {e(count_text)}.']
    ev = col.evaluation
    if ev is not None:
        scored = f"{ev['joined']} job{'s' if ev['joined'] != 1 else ''} scored"
        if ev.get("unscored"):
            scored += f", {ev['unscored']} not scored"
        bits = [f'Metrics from <a href="{e(url_of(ev["file"]))}">{e(field_text(ev["file"].name))}</a> ({scored})']
        prot = ", ".join(e(field_text(ev[k], METRIC_NAME_CHARS)) for k in ("protocol", "encoding", "region")
                         if ev.get(k))
        if prot:
            bits.append(f"protocol {prot}")
        means = ev.get("mean") or {}
        if any(means.get(m) is not None for m in col.metrics):
            bits.append("means " + ", ".join(f"{e(field_text(m, METRIC_NAME_CHARS))} {_fmt(means.get(m))}"
                                             for m in col.metrics))
        if ev.get("unavailable"):
            bits.append("unavailable: " + ", ".join(e(field_text(m, METRIC_NAME_CHARS)) for m in ev["unavailable"]))
        head.append(" " + "; ".join(bits) + ".")
    elif total:
        head.append(" No metrics: run <code>zcomp eval OUT</code> to add them.")
    head.append("</p>")
    now = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    head.append(f'<p class="meta">Written by <code>zcomp report</code> (zcomp {e(version)}) on {e(now)}.</p>')
    if col.notes:
        items = "".join(f"<li>{e(field_text(n))}</li>" for n in col.notes[:200])
        more = f"<li>... and {len(col.notes) - 200} more</li>" if len(col.notes) > 200 else ""
        head.append(f'<details class="notes"><summary>{len(col.notes)} note{"s" if len(col.notes) != 1 else ""}'
                    f"</summary><ul>{items}{more}</ul></details>")
    previews = ""
    if col.previews:
        figs = []
        for p in col.previews:
            src = e(url_of(p["image"]))
            extra = f' (<a href="{e(url_of(p["json"]))}">details</a>)' if p["json"] is not None else ""
            if p.get("light"):
                extra += f'<br><span class="meta">{e(field_text(p["light"]))}</span>'
            scene = e(field_text(p["scene"]))
            figs.append(f'<figure><a href="{src}"><img class="preview" loading="lazy" decoding="async" '
                        f'src="{src}" alt="preview of {scene}"></a>'
                        f"<figcaption>{scene}{extra}</figcaption></figure>")
        previews = (f'<details id="previews" open><summary>Light preview sheets ({len(col.previews)})</summary>'
                    f'<div class="sheets">{"".join(figs)}</div></details>')
    data = script_json(page_data(col, page_size, urls))
    return fill(_PAGE, {"TITLE": e(field_text(title)), "HEAD": "".join(head), "PREVIEWS": previews, "CSS": _CSS, "JS": _JS,
                        "DATA": data, "NONCE": secrets.token_urlsafe(18)})


_SLOT = re.compile(r"%([A-Z]+)%")


def fill(template: str, values: dict[str, str]) -> str:
    """``template`` with each ``%NAME%`` replaced by ``values[NAME]``, in one pass: a
    value is never read again for slots (a preview named ``%DATA%.png`` stays that
    text; chained replaces pasted the data into its ``alt``). A slot without a value
    stays as it is."""
    return _SLOT.sub(lambda m: values.get(m.group(1), m.group(0)), template)


_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; img-src 'self' file: data:; style-src 'unsafe-inline'; script-src 'nonce-%NONCE%'">
<meta name="referrer" content="no-referrer">
<link rel="icon" href="data:,">
<title>%TITLE%</title>
<style>%CSS%</style>
</head>
<body>
<header>
<h1>%TITLE%</h1>
%HEAD%
</header>
%PREVIEWS%
<noscript><p class="warn">This page needs JavaScript to show its table.</p></noscript>
<div class="controls" id="controls">
<label>status <select id="status-filter"></select></label>
<label>filter <input id="text-filter" type="search" placeholder="job, scene, object, reason, light..." size="32"></label>
<label>rows per page <select id="page-size"></select></label>
<span class="pager"><button id="first" type="button" title="first page">&laquo;</button><button id="prev" type="button" title="previous page">&lsaquo;</button>
<span id="page-info"></span>
<button id="next" type="button" title="next page">&rsaquo;</button><button id="last" type="button" title="last page">&raquo;</button></span>
<span id="row-info"></span>
</div>
<table id="jobs"><thead><tr></tr></thead><tbody></tbody></table>
<p id="empty" hidden>No job matches.</p>
<script id="zcomp-data" type="application/json">%DATA%</script>
<script nonce="%NONCE%">%JS%</script>
</body>
</html>
"""

_CSS = """
:root { color-scheme: light dark; --line: #8884; --muted: #888; }
body { font: 14px/1.35 system-ui, sans-serif; margin: 1em 1.5em; }
h1 { font-size: 1.4em; margin: 0 0 .3em; }
.meta { margin: .2em 0; color: var(--muted); }
.meta a { color: inherit; }
.notes { margin: .4em 0; }
#previews { margin: .8em 0; }
.sheets { display: flex; flex-wrap: wrap; gap: 1em; }
.sheets figure { margin: .4em 0; }
img.preview { max-width: 480px; height: auto; border: 1px solid var(--line); display: block; }
.sheets figcaption { max-width: 480px; }
.controls { position: sticky; top: 0; z-index: 2; background: Canvas; padding: .5em 0; display: flex;
  flex-wrap: wrap; gap: .6em 1.2em; align-items: center; border-bottom: 1px solid var(--line); }
.pager button { min-width: 2em; }
#page-info { display: inline-block; min-width: 7em; text-align: center; }
#row-info { color: var(--muted); }
table { border-collapse: collapse; margin-top: .5em; }
th, td { border-bottom: 1px solid var(--line); padding: 4px 8px; vertical-align: top; text-align: left; }
th { position: sticky; top: var(--controls-h, 2.6em); background: Canvas; cursor: pointer; user-select: none; white-space: nowrap; }
th:focus { outline: 2px solid #48f; }
th[aria-sort="ascending"]::after { content: " \\25B2"; }
th[aria-sort="descending"]::after { content: " \\25BC"; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.wide { max-width: 26em; white-space: pre-wrap; overflow-wrap: anywhere; }
td.img { width: 160px; padding: 2px 4px; }
td.img img { width: 160px; max-height: 160px; height: auto; object-fit: contain; display: block; }
td.img a.crop { display: block; position: relative; overflow: hidden; }
td.img a.crop img { position: absolute; max-width: none; max-height: none; height: auto; }
.none { color: var(--muted); }
.st { font-weight: 600; }
.st-done { color: #2a2; } .st-failed, .st-damaged { color: #d33; } .st-missing, .st-changed { color: #c80; }
.warn { color: #d33; }
"""

_JS = r"""
(function () {
  "use strict";
  var DATA = JSON.parse(document.getElementById("zcomp-data").textContent);
  var COLS = DATA.columns, ROWS = DATA.rows, N = ROWS.length, NC = COLS.length;
  var RANK = {};
  DATA.statuses.forEach(function (s, i) { RANK[s] = i; });
  var state = {sort: -1, dir: 1, status: "all", q: "", page: 0, size: DATA.pageSize};
  var keyCache = {}, order = null, hay = null, view = [];
  var collator = new Intl.Collator(undefined, {numeric: true, sensitivity: "base"});
  var $ = function (id) { return document.getElementById(id); };

  function num(v) {
    if (typeof v === "number") return v;
    if (v === "inf") return Infinity;
    if (v === "-inf") return -Infinity;
    return null;
  }
  function fmt(v) {
    if (v === Infinity) return "inf";
    if (v === -Infinity) return "-inf";
    var a = Math.abs(v);  // three significant digits: a metric's noise is in the fourth
    if (a !== 0 && (a < 1e-3 || a >= 1e4)) return a >= 1e4 ? v.toFixed(0) : v.toExponential(2);
    return String(Number(v.toPrecision(3)));
  }
  // Sort keys of a column, once: numbers; strings replaced by their rank in collation
  // order, so that sorting compares numbers only; null where the value is missing.
  function keysOf(c) {
    if (keyCache[c]) return keyCache[c];
    var t = COLS[c].type, k = new Array(N), i, v;
    for (i = 0; i < N; i++) {
      v = ROWS[i][c];
      if (v === null || v === undefined || v === "") k[i] = null;
      else if (t === "num") k[i] = num(v);
      else if (t === "status") k[i] = (v in RANK) ? RANK[v] : DATA.statuses.length;
      else k[i] = String(v);
    }
    if (t !== "num" && t !== "status") {
      var uniq = Array.from(new Set(k.filter(function (x) { return x !== null; }))).sort(collator.compare);
      var rank = new Map();
      uniq.forEach(function (s, j) { rank.set(s, j); });
      for (i = 0; i < N; i++) if (k[i] !== null) k[i] = rank.get(k[i]);
    }
    return (keyCache[c] = k);
  }
  function sortOrder() {
    var idx = new Array(N), i;
    for (i = 0; i < N; i++) idx[i] = i;
    if (state.sort < 0) return idx;
    var k = keysOf(state.sort), d = state.dir;
    idx.sort(function (a, b) {
      var x = k[a], y = k[b];
      if (x === null || y === null) {  // missing values last, both ways
        if (x === y) return a - b;
        return x === null ? 1 : -1;
      }
      if (x < y) return -d;
      if (x > y) return d;
      return a - b;
    });
    return idx;
  }
  function haystack() {
    if (hay) return hay;
    hay = new Array(N);
    var textCols = [];
    COLS.forEach(function (c, j) { if (c.type === "text" || c.type === "status") textCols.push(j); });
    var extra0 = NC;
    for (var i = 0; i < N; i++) {
      var parts = [];
      for (var j = 0; j < textCols.length; j++) { var v = ROWS[i][textCols[j]]; if (v) parts.push(v); }
      for (var x = extra0; x < ROWS[i].length; x++) if (ROWS[i][x]) parts.push(ROWS[i][x]);
      hay[i] = parts.join("\n").toLowerCase();
    }
    return hay;
  }
  function refilter() {
    if (!order) order = sortOrder();
    var st = state.status, q = state.q.trim().toLowerCase(), sc = statusCol, h = q ? haystack() : null;
    view = [];
    for (var i = 0; i < N; i++) {
      var r = order[i];
      if (st !== "all" && ROWS[r][sc] !== st) continue;
      if (q && h[r].indexOf(q) < 0) continue;
      view.push(r);
    }
  }
  function el(tag, cls, text) {
    var e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined && text !== null) e.textContent = text;
    return e;
  }
  // The composite's region [x0, y0, x1, y1] of its W x H pixels, shown in a box of at
  // most 160 x 160: the image itself scaled and moved in a clipping box (no file made).
  function closeup(v) {
    var x0 = v[1], y0 = v[2], w = Math.max(1, v[3] - v[1]), h = Math.max(1, v[4] - v[2]);
    var s = Math.min(160 / w, 160 / h);
    var box = el("a", "crop"); box.href = v[0];
    box.style.width = Math.round(w * s) + "px"; box.style.height = Math.round(h * s) + "px";
    var img = el("img"); img.loading = "lazy"; img.decoding = "async"; img.alt = "close-up"; img.src = v[0];
    img.style.width = Math.round(v[5] * s) + "px";
    img.style.left = -Math.round(x0 * s) + "px"; img.style.top = -Math.round(y0 * s) + "px";
    box.appendChild(img);
    return box;
  }
  function cell(row, c) {
    var col = COLS[c], v = row[c], td = document.createElement("td");
    td.setAttribute("data-key", col.key);
    if (col.type === "crop") {
      td.className = "img";
      if (v) td.appendChild(closeup(v));
      else td.appendChild(el("span", "none", "\u2014"));
    } else if (col.type === "img") {
      td.className = "img";
      if (v) {
        var a = el("a"); a.href = v;
        var img = el("img"); img.loading = "lazy"; img.decoding = "async"; img.alt = col.label; img.src = v;
        img.width = 160;
        a.appendChild(img); td.appendChild(a);
      } else td.appendChild(el("span", "none", "\u2014"));
    } else if (col.type === "num") {
      td.className = "num";
      var n = num(v);
      if (n === null) { td.appendChild(el("span", "none", "\u2014")); td.setAttribute("data-value", ""); }
      else { td.textContent = fmt(n); td.setAttribute("data-value", String(n)); }
    } else if (col.type === "status") {
      td.appendChild(el("span", "st st-" + String(v).replace(/[^a-z]/g, ""), v));
      td.setAttribute("data-value", v);
    } else {
      if (col.wide) td.className = "wide";
      if (v === null || v === undefined || v === "") td.appendChild(el("span", "none", "\u2014"));
      else td.textContent = v;
    }
    if (col.tip) {
      var t = row[NC + DATA.extra.indexOf(col.tip)];
      if (t) td.title = t;
    }
    return td;
  }
  function render() {
    var size = state.size > 0 ? state.size : N || 1;
    var pages = Math.max(1, Math.ceil(view.length / size));
    state.page = Math.min(Math.max(0, state.page), pages - 1);
    var start = state.page * size, end = Math.min(view.length, start + size);
    var tbody = document.createElement("tbody"), frag = document.createDocumentFragment();
    for (var i = start; i < end; i++) {
      var r = view[i], row = ROWS[r], tr = document.createElement("tr");
      tr.setAttribute("data-row", r);
      for (var c = 0; c < NC; c++) tr.appendChild(cell(row, c));
      frag.appendChild(tr);
    }
    tbody.appendChild(frag);
    var table = $("jobs");
    table.replaceChild(tbody, table.tBodies[0]);
    $("page-info").textContent = "page " + (state.page + 1) + " of " + pages;
    $("row-info").textContent = view.length
      ? "rows " + (start + 1) + "\u2013" + end + " of " + view.length + (view.length !== N ? " (" + N + " in all)" : "")
      : "0 of " + N + " rows";
    $("empty").hidden = view.length > 0;
    $("first").disabled = $("prev").disabled = state.page === 0;
    $("next").disabled = $("last").disabled = state.page >= pages - 1;
    var ths = table.tHead.rows[0].cells;
    for (var j = 0; j < ths.length; j++)
      ths[j].setAttribute("aria-sort", j === state.sort ? (state.dir > 0 ? "ascending" : "descending") : "none");
    document.body.setAttribute("data-page", String(state.page + 1));
    document.body.setAttribute("data-pages", String(pages));
  }
  function update(resort) {
    if (resort) order = null;
    refilter();
    render();
  }

  var statusCol = -1;
  var tr = $("jobs").tHead.rows[0];
  COLS.forEach(function (c, j) {
    if (c.type === "status") statusCol = j;
    var th = el("th", null, c.label);
    th.setAttribute("data-key", c.key);
    th.setAttribute("data-col", String(j));
    th.setAttribute("tabindex", "0");
    th.setAttribute("aria-sort", "none");
    th.title = (c.title ? c.title + "; " : "") + "click to sort";
    var go = function () {
      if (state.sort === j) state.dir = -state.dir; else { state.sort = j; state.dir = 1; }
      state.page = 0;
      update(true);
    };
    th.addEventListener("click", go);
    th.addEventListener("keydown", function (ev) { if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); go(); } });
    tr.appendChild(th);
  });

  var counts = {};
  ROWS.forEach(function (r) { counts[r[statusCol]] = (counts[r[statusCol]] || 0) + 1; });
  var sel = $("status-filter");
  sel.appendChild(new Option("all (" + N + ")", "all"));
  DATA.statuses.forEach(function (s) { if (counts[s]) sel.appendChild(new Option(s + " (" + counts[s] + ")", s)); });
  sel.addEventListener("change", function () { state.status = sel.value; state.page = 0; update(false); });

  var q = $("text-filter");
  q.addEventListener("input", function () { state.q = q.value; state.page = 0; update(false); });

  var ps = $("page-size"), sizes = [25, 50, 100, 250, 1000];
  if (sizes.indexOf(state.size) < 0) { sizes.push(state.size); sizes.sort(function (a, b) { return a - b; }); }
  sizes.forEach(function (n) { ps.appendChild(new Option(String(n), String(n))); });
  ps.appendChild(new Option("all", "0"));
  ps.value = String(state.size);
  ps.addEventListener("change", function () {
    var first = state.page * (state.size || N);
    state.size = parseInt(ps.value, 10);
    state.page = state.size > 0 ? Math.floor(first / state.size) : 0;
    render();
  });
  $("first").addEventListener("click", function () { state.page = 0; render(); });
  $("prev").addEventListener("click", function () { state.page -= 1; render(); });
  $("next").addEventListener("click", function () { state.page += 1; render(); });
  $("last").addEventListener("click", function () { state.page = 1e9; render(); });

  // the header row sticks just below the controls, whose height depends on the window
  var stick = function () {
    document.documentElement.style.setProperty("--controls-h", $("controls").offsetHeight + "px");
  };
  window.addEventListener("resize", stick);
  stick();
  update(true);
  document.body.setAttribute("data-ready", "1");
})();
"""

__all__ = ["columns", "fill", "page_data", "render_page", "script_json"]
