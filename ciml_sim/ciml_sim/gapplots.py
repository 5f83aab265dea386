"""The randomised gap-bench's pictures and report.html (issue 31 item 3): the calibration curve, the
confusion matrix and the detection limits as PNG files beside gap_bench.json.

matplotlib's Agg backend (no display); every file is rendered in memory and written whole (atomic).
"""
from __future__ import annotations

import html
import io
import json
import os

import numpy as np

from ciml_learning.core.fileio import atomic_write_bytes, atomic_write_text

from .gapstats import NOMINAL_ROW, NOTHING, UNEXPLAINED, WRONG_PLACE

PLOTS = ("calibration.png", "confusion.png", "detection.png")


def _save(fig, path: str) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    atomic_write_bytes(path, buf.getvalue())


def calibration_figure(summary: dict):
    """Nominal vs measured coverage, overall (with Wilson 95 % bars) and per effect type."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="ideal")
    for t, s in summary["per_type"].items():
        pts = [(float(p), r["fraction"]) for p, r in s["calibration"].items() if r["n"]]
        if pts:
            ax.plot(*zip(*pts), lw=0.8, alpha=0.5, marker=".", label=f"{t} ({s['calibration']['0.95']['n']})")
    pts = [(float(p), r) for p, r in summary["calibration"].items() if r["n"]]
    if pts:
        x = np.array([p for p, _ in pts])
        y = np.array([r["fraction"] for _, r in pts])
        err = np.array([[r["fraction"] - r["ci95"][0], r["ci95"][1] - r["fraction"]] for _, r in pts]).T
        ax.errorbar(x, y, yerr=err, color="k", lw=2, marker="o", capsize=3,
                    label=f"all ({pts[0][1]['n']} parameters)")
    ax.set(xlabel="nominal coverage of the interval", ylabel="measured coverage", xlim=(0.4, 1.01),
           ylim=(0, 1.01), title="calibration of the reported intervals")
    ax.legend(fontsize=6, loc="lower right")
    return fig


def confusion_figure(confusion: dict[str, dict[str, int]]):
    """Rows: the true effect (or none); columns: what the diagnosis named; each cell a count."""
    import matplotlib.pyplot as plt

    rows = sorted(r for r in confusion if r != NOMINAL_ROW) + ([NOMINAL_ROW] if NOMINAL_ROW in confusion else [])
    named = {n for r in confusion.values() for n in r}
    cols = [r for r in rows if r in named] + sorted(named - set(rows) - {WRONG_PLACE, UNEXPLAINED, NOTHING})
    cols += [c for c in (WRONG_PLACE, UNEXPLAINED, NOTHING) if c in named]
    m = np.array([[confusion[r].get(c, 0) for c in cols] for r in rows], float).reshape(len(rows), len(cols))
    fig, ax = plt.subplots(figsize=(1.2 + 0.45 * max(len(cols), 1), 1.2 + 0.4 * max(len(rows), 1)))
    if m.size == 0:  # no case scored yet (a partial bench): an empty image has no extent
        ax.text(0.5, 0.5, "no case scored", ha="center", va="center", transform=ax.transAxes)
    else:
        ax.imshow(m / np.maximum(m.sum(axis=1, keepdims=True), 1), cmap="Blues", vmin=0, vmax=1)
    for i, j in zip(*np.nonzero(m)):
        ax.text(j, i, f"{int(m[i, j])}", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=7)
    ax.set(xlabel="named by the diagnosis", ylabel="true effect", title="confusion (counts; colour: row share)")
    return fig


def detection_figure(cases: list[dict], summary: dict):
    """Per effect type: each draw's size against named right or not, and the detection limit."""
    import matplotlib.pyplot as plt

    types = list(summary["per_type"])
    n = max(len(types), 1)
    cols = min(3, n)
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(3.6 * cols, 2.2 * ((n + cols - 1) // cols)),
                             squeeze=False)
    for ax, t in zip(axes.flat, types):
        rows = [r for c in cases if "error" not in c for r in c["effects"] if r["type"] == t]
        hit = np.array([bool(r["type_right"] and r["location_right"]) for r in rows])
        size = np.array([r["size"] for r in rows])
        ax.scatter(size[hit], np.ones(hit.sum()), marker="o", color="tab:green", label="named right")
        ax.scatter(size[~hit], np.zeros((~hit).sum()), marker="x", color="tab:red", label="missed")
        lim = summary["per_type"][t]["detection_limit"]
        if lim.get("limit") is not None:
            ax.axvline(lim["limit"], color="k", ls="--", lw=1)
        shown = f"— ({lim['why'].split(':')[0].split(' (')[0]})" if lim.get("limit") is None else f"{lim['limit']:.3g}"
        ax.set_title(f"{t}: limit {shown}", fontsize=8)
        ax.set_xlabel(summary["per_type"][t]["size"], fontsize=7)
        ax.set_yticks([0, 1], ["missed", "named"], fontsize=7)
        ax.set_ylim(-0.5, 1.5)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(types):]:
        ax.axis("off")
    fig.tight_layout()
    return fig


def _rate(r: dict) -> str:
    if not r or not r.get("n"):
        return "—"
    return f"{r['k']}/{r['n']} = {r['fraction']:.1%} [{r['ci95'][0]:.1%}, {r['ci95'][1]:.1%}]"


def per_type_table(summary: dict) -> str:
    """Markdown: per effect type, named right, 68 % and 95 % coverage (Wilson 95 %), detection limit."""
    lines = ["| effect type | named right | coverage 68 % | coverage 95 % | detection limit (size) | "
             "median param. error |", "|---|---|---|---|---|---|"]
    for t, s in summary["per_type"].items():
        lim = s["detection_limit"]
        dl = f"{lim['limit']:.3g}" if lim.get("limit") is not None else lim["why"]
        err = "—" if s["median_param_rel_error"] is None else f"{s['median_param_rel_error']:.3f}"
        lines.append(f"| {t} | {_rate(s['named_right'])} | {_rate(s['calibration']['0.68'])} "
                     f"| {_rate(s['calibration']['0.95'])} | {dl} ({s['size']}) | {err} |")
    return "\n".join(lines)


def overall_table(summary: dict) -> str:
    """Markdown: the overall scores with their Wilson 95 % intervals, and the calibration levels."""
    rows = [("named right (type and place)", _rate(summary["named_right"])),
            ("false positives (nominal cases naming an effect)", _rate(summary["false_positive_nominal"])),
            ("nominal cases reported 'unexplained'", _rate(summary["unexplained_alarm_nominal"])),
            ("out of catalogue: unexplained and localised",
             _rate(summary["out_of_catalogue_unexplained_and_localised"])),
            ("catalogue cases with a spurious effect (share > 5 %)", _rate(summary["cases_with_spurious_effect"]))]
    rows += [(f"coverage of the {float(p):.0%} intervals", _rate(r)) for p, r in summary["calibration"].items()]

    def fmt(x: float | None) -> str:
        return "—" if x is None else f"{x:.3f}"

    rows += [("median parameter relative error", fmt(summary["median_param_rel_error"])),
             ("median held-out shrink (normalised / physical)",
              f"{fmt(summary['median_heldout_shrink'])} / {fmt(summary['median_heldout_shrink_physical'])}"),
             ("median re-simulated shrink (identified / oracle)",
              f"{fmt(summary['median_resimulated_shrink'])} / {fmt(summary['median_resimulated_shrink_oracle'])}")]
    return "\n".join(["| score | measured (Wilson 95 % interval) |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows])


def confusion_table(confusion: dict[str, dict[str, int]]) -> str:
    """Markdown: the confusion matrix, one row per true effect, the named columns that occur."""
    rows = sorted(r for r in confusion if r != NOMINAL_ROW) + ([NOMINAL_ROW] if NOMINAL_ROW in confusion else [])
    cols = sorted({n for r in confusion.values() for n in r} - {WRONG_PLACE, UNEXPLAINED, NOTHING})
    cols += [c for c in (WRONG_PLACE, UNEXPLAINED, NOTHING) if any(c in r for r in confusion.values())]
    lines = ["| true ↓ / named → | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    lines += [f"| {r} | " + " | ".join(str(confusion[r].get(c, "")) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def write_report(out_dir: str, doc: dict) -> None:
    """DIR/calibration.png, confusion.png, detection.png and report.html (tables, plots, the summary JSON)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = doc["summary"]
    for name, fig in zip(PLOTS, (calibration_figure(summary), confusion_figure(summary["confusion"]),
                                 detection_figure(doc["cases"], summary))):
        _save(fig, os.path.join(out_dir, name))
        plt.close(fig)
    r = doc["random"]
    title = f"gap-bench, {r['n']} random cases, seed {r['seed']}" + (" (partial)" if doc.get("partial") else "")

    def table_html(md: str) -> str:
        lines = [ln.strip("|").split("|") for ln in md.splitlines() if not ln.startswith("|---")]
        cells = ["<tr>" + "".join(f"<{'th' if i == 0 else 'td'}>{html.escape(c.strip())}</{'th' if i == 0 else 'td'}>"
                                  for c in ln) + "</tr>" for i, ln in enumerate(lines)]
        return "<table>" + "".join(cells) + "</table>"

    body = (f"<h1>{html.escape(title)}</h1><p>engine {html.escape(str(doc.get('engine')))}, wall "
            f"{doc.get('wall_s')} s, {summary['cases']} cases ({summary['failed_cases']} failed), kinds "
            f"{html.escape(json.dumps(summary['kinds']))}. Data: <a href='gap_bench.json'>gap_bench.json</a>, "
            f"the draw: <a href='draws.json'>draws.json</a>.</p>"
            + table_html(overall_table(summary)) + "<h2>Per effect type</h2>" + table_html(per_type_table(summary))
            + "".join(f"<h2>{n[:-4]}</h2><img src='{n}'>" for n in PLOTS)
            + "<h2>Summary (JSON)</h2><pre>" + html.escape(json.dumps(summary, indent=1)) + "</pre>")
    atomic_write_text(os.path.join(out_dir, "report.html"),
                      "<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title)
                      + "</title><style>body{font-family:sans-serif;max-width:1100px}td,th{border:1px solid #ccc;"
                      "padding:2px 6px;font-size:13px}table{border-collapse:collapse}</style></head><body>"
                      + body + "</body></html>\n")
