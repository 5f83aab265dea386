"""report.html: a self-contained page (plots embedded as base64 PNG) answering the three
questions of docs/ARCHITECTURE.md §6 — where the gap lies, which effect causes it, how far it shrinks."""
from __future__ import annotations

import base64
import html
import io
import os

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.diagnosis.files import REPORT_HTML, read_diagnosis_json, write_diagnosis_dir
from ciml_learning.effects import EFFECTS


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _fmt_params(params: dict, std: dict) -> str:
    parts = []
    for k, v in params.items():
        s = std.get(k)
        if isinstance(v, list):
            vs = ", ".join(f"{x:.4g}" for x in v)
            ss = ", ".join(f"{x:.2g}" for x in s) if isinstance(s, list) else ""
            parts.append(f"{k} = [{vs}] ± [{ss}]")
        else:
            parts.append(f"{k} = {v:.4g} ± {s:.2g}" if isinstance(s, float) else f"{k} = {v:.4g}")
    return "; ".join(parts)


def unit_of(item: dict) -> str:
    """N for forces (base_fx… and feet), Nm for torques (base roll/pitch/yaw, actuators)."""
    name = item["dimension"]
    if item["kind"] == "actuation" or name in ("base_roll", "base_pitch", "base_yaw"):
        return "Nm"
    return "N"


def effect_location(e: dict) -> str:
    """Where an effect of the diagnosis acts: its joint or link, "all joints" or "base"."""
    return e.get("joint") or e.get("link") or ("all joints" if e.get("joints") == "all" else "base")


OUTSIDE_REPORTED = 0.01
"""Out-of-catalogue joint torques with a smaller share of the gap are left out of the answers."""


def answers(result: dict) -> list[str]:
    """The three answers in a few lines of plain text (also printed by `ciml diagnose`)."""
    loc = result["localization"]
    top = [f"{d['dimension']} ({d['share']:.0%}, RMS {d['rms_error']:.3g} {unit_of(d)})"
           for d in loc[:3] if d["share"] > 0]
    legs = sorted(result.get("localization_by_leg", {}).items(), key=lambda x: -x[1])
    where = "Where: " + (", ".join(top) if top else "no dimension stands above its noise level")
    if legs and legs[0][1] > 0:
        where += "; by part: " + ", ".join(f"{k} {v:.0%}" for k, v in legs[:3] if v > 0)
    eff = result["effects"]
    if eff:
        which = "Which: " + "; ".join(f"{e['type']} at {effect_location(e)} ({_fmt_params(e['params'], e['std'])}), "
                                      f"{e['share']:.0%} of the gap" for e in eff)
    else:
        which = "Which: no catalogue effect explains the gap"
    if eff:
        which = which.replace(" of the gap", " of the gap above noise")
        which += " [confidence: " + ", ".join(f"{effect_location(e)} {e.get('confidence')}" for e in eff) + "]"
    which += f"; unexplained: {result['unexplained_share']:.0%}"
    floor = result.get("noise_floor", {})
    if result.get("gap_at_noise_floor"):
        which += " (the held-out error is at the noise floor: nothing above noise to explain)"
    elif "share_of_nominal" in floor:
        which += f" of the gap above the noise floor (noise: {floor['share_of_nominal']:.0%} of the nominal residual)"
    outside = [u for u in result.get("unexplained_localised", []) if u["share"] >= OUTSIDE_REPORTED]
    if outside:
        which += " — of it, a joint torque no catalogue effect explains at " + "; ".join(
            f"{u['joint']} ({u['share']:.0%}: {u['torque_at_center']:.3g} Nm at q = {u['position_center']:.3g} rad, "
            f"stiffness {u['stiffness']:.3g} Nm/rad{', in the torque reading' if u.get('level') == 'sensor' else ''})"
            for u in outside)
    for e in result.get("not_identified", []):
        which += f"; {e['type']} at {effect_location(e)}: at bound — not identified ({_fmt_params(e['params'], {})})"
    s = result["shrink"]
    far = (f"How far: on held-out data the gap shrinks by {s['ratio']:.0%} "
           f"(noise-normalised RMS {s['heldout_rms_nominal']:.3g} → {s['heldout_rms_with_effects']:.3g})")
    if "ratio_physical_per_dimension" in s:
        far += f"; in physical units (N, Nm; per dimension) by {s['ratio_physical_per_dimension']:.0%}"
    worse = s.get("worsened_dimensions", [])
    far += ("; made worse: " + ", ".join(f"{w['dimension']} ({w['rms_nominal']:.3g} → {w['rms_with_effects']:.3g} "
                                          f"{w['unit']})" for w in worse)) if worse else "; no dimension made worse"
    out = [where, which, far]
    comp = result.get("reference_comparison")
    if comp is not None:
        diffs = comp["differences"]
        line = "Against the reference: " + ("; ".join(
            f"{d['type']} at {d['where']} ({d['status']}"
            + (f": {_fmt_params(d['params'], d['std'])})" if "params" in d else
               f": real − reference = {_fmt_params(d['difference'], d['difference_std'])})") for d in diffs)
            if diffs else "no effect distinguishes the logs from the reference")
        shared = [x for x in comp["effects"] if x["status"] == "shared"]
        if shared:
            line += "; shared by both (not a gap between them): " + ", ".join(f"{x['type']} at {x['where']}"
                                                                              for x in shared)
        out.append(line)
    return out


def _gapped(t: np.ndarray, *ys: np.ndarray):
    """Time axis without the gaps between bags, and NaN where samples are missing (breaks the lines)."""
    if len(t) == 0:
        return (t, *ys)
    dt = np.diff(t)
    step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    jumps = (dt <= 0) | (dt > 1.0)               # a new bag (time restarts or jumps)
    tt = np.concatenate([[0.0], np.cumsum(np.where(jumps, step, dt))])
    gap = np.concatenate([[False], dt > 1.5 * step])
    out = [np.where(gap, np.nan, y) for y in ys]
    return (tt, *out)


CLOSED_LOOP_BEGIN, CLOSED_LOOP_END = "<!--closed-loop-->", "<!--/closed-loop-->"


def closed_loop_html(closed_loop: dict | None) -> str:
    """Table of closed-loop metrics per model (nominal / identified effects / learned)."""
    if not closed_loop:
        return ("<p>No closed-loop run attached yet: <code>ciml closed-loop --scenario S.yaml --motion M "
                "--model DIR --report DIR</code> runs the controller with the nominal model plus these effects "
                "(DIR = this report's folder) and adds the result here; with <code>--model nominal</code> or "
                "<code>--model MODEL_DIR</code> (a learned model) it adds those for comparison.</p>")
    keys = [("rms_feedback_effort_nm", "RMS feedback effort [Nm]"), ("rms_joint_error_deg", "RMS joint error [deg]"),
            ("rms_attitude_error_deg", "RMS attitude error [deg]"),
            ("rms_base_position_error_mm", "RMS base position error [mm]"), ("fell", "fell")]
    head = "".join(f"<th>{html.escape(label)}</th>" for _, label in keys)
    body = ""
    for name, m in closed_loop.items():
        cells = "".join(f"<td>{m.get(k):.3g}</td>"
                        if isinstance(m.get(k), (int, float)) and not isinstance(m.get(k), bool)
                        else f"<td>{html.escape(str(m.get(k, '')))}</td>" for k, _ in keys)
        body += f"<tr><td>{html.escape(name)}</td>{cells}</tr>"
    return f"<table><tr><th>model</th>{head}</tr>{body}</table>"


def attach_closed_loop(diagnosis_dir: str, closed_loop: dict) -> None:
    """Add closed-loop metrics ({model name: `ciml closed-loop` metrics}) to DIR/diagnosis.json and
    DIR/report.html: the directory is rebuilt and replaced in one step (files.write_diagnosis_dir),
    so a reader finds both files old or both new."""
    doc = read_diagnosis_json(diagnosis_dir)
    doc["closed_loop"] = closed_loop
    page = None
    try:
        with open(os.path.join(diagnosis_dir, REPORT_HTML), encoding="utf-8") as f:
            page = f.read()
    except FileNotFoundError:
        pass
    except (OSError, UnicodeDecodeError) as err:
        raise CimlError(f"--report {diagnosis_dir}: cannot read {REPORT_HTML} ({err})") from None
    if page is not None:
        a, b = page.find(CLOSED_LOOP_BEGIN), page.find(CLOSED_LOOP_END)
        if a >= 0 and b > a:
            page = page[:a + len(CLOSED_LOOP_BEGIN)] + closed_loop_html(closed_loop) + page[b:]
    write_diagnosis_dir(diagnosis_dir, doc, page, what="--report", update=True)


def render_report(robot, result: dict, series: dict, rows_ho, selection) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loc = result["localization"]
    order = {d: i for i, d in enumerate([*robot.rbd_error_names,
                                         *[j[:-6] if j.endswith("_joint") else j for j in robot.joint_names]])}
    dims = sorted(loc, key=lambda d: order.get(d["dimension"], 99))
    names = [d["dimension"] for d in dims]
    x = np.arange(len(dims))
    figs = {}

    # 1. where: error per dimension by phase, relative to noise; by contact configuration; by speed
    fig, axes = plt.subplots(3, 1, figsize=(13, 11))
    ax = axes[0]
    for k, (phase, col) in enumerate((("stance", "tab:blue"), ("swing", "tab:orange"))):
        vals = [d.get("by_phase", {}).get(phase, np.nan) / d["noise_level"] for d in dims]
        ax.bar(x + (k - 0.5) * 0.4, vals, 0.4, label=phase, color=col)
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise level")
    ax.set_xticks(x, names, rotation=70, fontsize=8)
    ax.set_ylabel("RMS error / noise level")
    ax.set_title("Where: measured error per dimension (Φ̃' base/feet, Γ actuators), stance vs swing")
    ax.legend(fontsize=8)
    configs = sorted({c for d in dims for c in d.get("by_contacts", {})})
    mat = np.array([[d.get("by_contacts", {}).get(c, np.nan) / d["noise_level"] for d in dims] for c in configs]) \
        if configs else np.zeros((1, len(dims)))
    ax = axes[1]
    im = ax.imshow(mat, aspect="auto", cmap="viridis")
    ax.set_yticks(np.arange(len(configs)), configs if configs else [""], fontsize=7)
    ax.set_xticks(x, names, rotation=70, fontsize=8)
    ax.set_title("by contact configuration (feet on the ground): RMS error / noise level")
    fig.colorbar(im, ax=ax, fraction=0.02)
    ax = axes[2]
    for k, (b, col) in enumerate((("slow", "tab:green"), ("medium", "tab:olive"), ("fast", "tab:red"))):
        vals = [d.get("by_speed", {}).get(b, np.nan) / d["noise_level"] for d in dims]
        ax.bar(x + (k - 1) * 0.27, vals, 0.27, label=b, color=col)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(x, names, rotation=70, fontsize=8)
    ax.set_ylabel("RMS error / noise level")
    ax.set_title("by speed tercile (base: linear speed; feet and actuators: their leg's joint speed)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    figs["where"] = _png(fig)

    # 2. which: shares
    eff = result["effects"]
    fig, ax = plt.subplots(figsize=(9, 0.5 * (len(eff) + 2) + 1))
    labels = [f"{e['type']} @ {effect_location(e)}" for e in eff] + ["unexplained"]
    shares = [e["share"] for e in eff] + [result["unexplained_share"]]
    colors = ["tab:blue"] * len(eff) + ["tab:gray"]
    ax.barh(np.arange(len(labels)), shares, color=colors)
    ax.set_yticks(np.arange(len(labels)), labels, fontsize=9)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of the held-out gap (noise-normalised sum of squares)")
    ax.set_title("Which: identified effects")
    figs["which"] = _png(fig)

    # 3. how far: per dimension before/after, and over time
    per = result["shrink"]["per_dimension"]
    fig, axes = plt.subplots(2, 1, figsize=(13, 8))
    ax = axes[0]
    sig = {d["dimension"]: d["noise_level"] for d in loc}
    pn = [per.get(n, {}).get("rms_nominal", np.nan) / sig[n] for n in names]
    pw = [per.get(n, {}).get("rms_with_effects", np.nan) / sig[n] for n in names]
    ax.bar(x - 0.2, pn, 0.4, label="nominal model", color="tab:red")
    ax.bar(x + 0.2, pw, 0.4, label="with identified effects", color="tab:green")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise level")
    ax.set_xticks(x, names, rotation=70, fontsize=8)
    ax.set_ylabel("held-out RMS / noise level")
    ax.set_yscale("log")
    ax.set_title("How far: held-out residual per dimension (log scale)")
    ax.legend(fontsize=8)
    ax = axes[1]
    t, nominal, with_eff = _gapped(series["t"], series["nominal"], series["with_effects"])
    ax.plot(t, nominal, lw=0.8, color="tab:red", label="nominal model")
    ax.plot(t, with_eff, lw=0.8, color="tab:green", label="with identified effects")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("held-out time [s] (valid samples; bags one after the other)")
    ax.set_ylabel("RMS over dimensions of error / noise")
    ax.set_yscale("log")
    ax.set_title("held-out residual over time (log scale)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    figs["far"] = _png(fig)

    a = answers(result)
    e = html.escape
    rows = "".join(
        f"<tr><td>{e(x['type'])}<br><small>{e(_wording(x['type']))}</small></td><td>{e(effect_location(x))}</td>"
        f"<td>{e(_fmt_params(x['params'], x['std']))}</td>"
        f"<td>{x['share']:.1%}</td>"
        f"<td>{e(x.get('confidence', ''))} (spread {x.get('consistency_spread', 0):.0%})</td></tr>"
        for x in eff) or "<tr><td colspan=5>none</td></tr>"
    loc_rows = "".join(
        f"<tr><td>{e(d['dimension'])}</td><td>{d['kind']}</td><td>{d['rms_error']:.3g}</td>"
        f"<td>{d['relative_error']:.2%}</td><td>{d['noise_level']:.3g}</td><td>{d['share']:.1%}</td></tr>"
        for d in loc[:12])
    steps = "".join(f"<li>{e(s['accepted'])}: {s['gain_share']:.2%} of the gap"
                    + (f" (runner-up {e(s['runner_up'])}: {s['runner_up_share']:.2%})" if s.get("runner_up") else "")
                    + "</li>" for s in result["selection"]["steps"])
    d = result["data"]
    s = result["shrink"]
    outside_rows = "".join(
        f"<tr><td>&nbsp;&nbsp;of it: joint torque outside the catalogue</td><td>{e(u['joint'])}</td>"
        f"<td>{u['torque_at_center']:.3g} Nm at q = {u['position_center']:.3g} rad, "
        f"stiffness {u['stiffness']:.3g} Nm/rad; "
        f"position-dependent part {u['torque_position_dependent_rms']:.3g} Nm RMS</td>"
        f"<td>{u['share']:.1%}</td><td></td></tr>"
        for u in result.get("unexplained_localised", []) if u["share"] >= OUTSIDE_REPORTED)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>CIML gap diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}
.ans{{background:#f4f4f8;padding:0.6em 1em;border-left:4px solid #446}}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<div class="ans"><p>{e(a[0])}</p><p>{e(a[1])}</p><p>{e(a[2])}</p></div>
<h2>1. Where does the gap lie?</h2>
<p>Error of the nominal model per dimension: the contact-invariant error Φ̃' (eq. 11: base force and
torque always, each foot's force while it swings) and the actuation error Γ = τ − u per joint (eq. 14),
over {d['samples'] + d['heldout_samples']} valid samples, after the baseline (below). Noise level: what no
catalogue effect explains; share: of the error above the noise level.</p>
<table><tr><th>dimension</th><th>kind</th><th>RMS error [N|Nm]</th><th>relative to signal</th>
<th>noise level</th><th>share of gap</th></tr>{loc_rows}</table>
<img src="{figs['where']}" style="width:100%">
<h2>2. Which unmodelled effect causes it?</h2>
<table><tr><th>effect</th><th>where</th><th>parameters ± std</th><th>share</th>
<th>confidence (parameter spread across contact configurations, bags, sliding speeds)</th></tr>{rows}
<tr><td colspan=3>unexplained (no candidate explains it)</td><td>{result['unexplained_share']:.1%}</td><td></td></tr>
{outside_rows}</table>
<img src="{figs['which']}" style="max-width:100%">
<p>Selection on held-out data ({len(eff)} of {result['selection']['candidates']} candidates kept):</p><ul>{steps}</ul>
<h2>3. How far does it shrink?</h2>
<p>Held-out: {e(d['heldout'])}; {d['heldout_samples']} samples. Noise-normalised RMS
{s['heldout_rms_nominal']:.3g} → {s['heldout_rms_with_effects']:.3g} (gap removed: {s['ratio']:.1%});
physical RMS (N and Nm mixed) {s['heldout_rms_nominal_physical']:.3g} →
{s['heldout_rms_with_effects_physical']:.3g}.</p>
<p>With the stiction of the identified Coulomb frictions estimated per sample (shrink.py): {s['ratio']:.1%};
without: {s['ratio_without_stiction_estimate']:.1%}.</p>
<img src="{figs['far']}" style="width:100%">
<h3>Closed loop: feedback effort and tracking, nominal vs identified effects vs learned</h3>
{CLOSED_LOOP_BEGIN}{closed_loop_html(result.get("closed_loop"))}{CLOSED_LOOP_END}
<h2>Data</h2><p>Identification bags: {e(', '.join(d['bags']))}<br>
Held-out bags: {e(', '.join(d['heldout_bags']) or '(part of the above)')}<br>
Samples: {d['samples']} identification, {d['heldout_samples']} held-out.
Rejected while reading: {e(str(d['rejected']))}.</p>
<h3>Baseline: command-update sampling</h3>
<p>{e(result["baseline"]["description"])}
Fitted: {e(_fmt_params(result["baseline"]["params"], result["baseline"]["std"]))}.
Held-out noise-normalised RMS before → after the baseline: {s["baseline"]["heldout_rms_before_baseline"]:.3g} →
{s["baseline"]["heldout_rms_after_baseline"]:.3g} (the "nominal" above is after it).</p>
</body></html>
"""


def _wording(effect_type: str) -> str:
    """The registry's sentence for an effect type (empty for a name it does not hold)."""
    kind = EFFECTS.get(effect_type)
    return kind.wording if kind is not None else ""
