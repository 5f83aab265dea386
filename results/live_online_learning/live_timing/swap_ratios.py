"""From a live_trace.py trace: at every change of the served model, the RMS feedback effort [Nm] of
the 5 s before and after it (the rollback's assessment), and the RMS per 30 s.

    python swap_ratios.py TRACE.npz
"""
import sys

import numpy as np

d = np.load(sys.argv[1])
t, e = d["eff"][:, 0], d["eff"][:, 1]
order = np.argsort(d["src_t"])
st, src = d["src_t"][order], d["src"][order]


def rms(a: float, b: float) -> float:
    m = (t >= a) & (t < b)
    return float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else float("nan")


for k in [0] + [k for k in range(1, len(src)) if src[k] != src[k - 1]]:
    s = st[k]
    print(f"{s - t[0]:7.1f} s  {src[k]:28s} before {rms(s - 5, s):.3f} after {rms(s, s + 5):.3f} "
          f"ratio {rms(s, s + 5) / rms(s - 5, s):.3f}")
print("per 30 s", [round(rms(a, a + 30), 3) for a in np.arange(t[0], t[-1], 30.0)])
