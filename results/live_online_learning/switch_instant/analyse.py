"""A live_trace.py trace: RMS feedback effort per 10 s; per window the joints' feedback and
tracking error, the predictions' RMS and the base's motion; and the /reference samples of a later
window against those of the same gait phase in 100–130 s (which fields differ, at which phase).

    python analyse.py TRACE.npz   → output.txt
"""
import sys

import numpy as np

d = np.load(sys.argv[1])
t0, nj = float(d["t0"]), 12
e = d["eff"]
span = int(e[-1, 0] - t0)
print("RMS feedback effort per 10 s [Nm]:",
      [round(float(np.sqrt(np.mean(e[(e[:, 0] - t0 >= a) & (e[:, 0] - t0 < a + 10), 1] ** 2))), 2)
       for a in range(0, span, 10)])
cmd, js, base, pred, ref = d["cmd"], d["js"], d["base"], d["pred"], d["ref"]
common, ci, ji = np.intersect1d(np.round((cmd[:, 0] - t0) * 1e3).astype(int),
                                np.round((js[:, 0] - t0) * 1e3).astype(int), return_indices=True)
t = common / 1e3
qt, vt, kp, kd = (cmd[ci, 3 + k * nj:3 + (k + 1) * nj] for k in (2, 3, 4, 5))
q, qd = js[ji, 2:2 + nj], js[ji, 2 + nj:2 + 2 * nj]
fb = kp * (qt - q) + kd * (vt - qd)
windows = [(100, 130), (290, 305), (305, 320), (320, 340), (400, 430), (560, 590)]
for a, b in windows:
    m = (t >= a) & (t < b)
    pm = (pred[:, 0] - t0 >= a) & (pred[:, 0] - t0 < b)
    bm = (base[:, 0] - t0 >= a) & (base[:, 0] - t0 < b)
    if not (m.any() and pm.any() and bm.any()):
        continue
    print(f"{a}-{b} s: feedback RMS {np.sqrt(np.mean(fb[m] ** 2)):.3f} Nm, position error RMS "
          f"{1e3 * np.sqrt(np.mean((qt - q)[m] ** 2)):.2f} mrad; prediction RMS rbd "
          f"{np.sqrt(np.mean(pred[pm, 1:19] ** 2)):.4f} actuation {np.sqrt(np.mean(pred[pm, 19:31] ** 2)):.4f}; "
          f"base angular velocity RMS {np.round(np.sqrt(np.mean(base[bm, 11:14] ** 2, 0)), 3).tolist()} rad/s")
rt, phase = ref[:, 0] - t0, ref[:, 1]
early = np.nonzero((rt >= 100) & (rt < 130))[0]
for a, b in ((290, 305), (305, 310), (310, 320), (400, 430), (560, 590)):
    rows, jumps = [], set()
    for j in np.nonzero((rt >= a) & (rt < b))[0]:
        k = early[np.argmin(np.abs(phase[early] - phase[j]))]
        if abs(phase[k] - phase[j]) > 1e-7:
            continue
        diff = np.abs(ref[k, 2:] - ref[j, 2:])
        rows.append(diff)
        if diff[2 * nj:3 * nj].max() > 1e-3:
            jumps.add(round(float(phase[j]), 4))
    if not rows:
        continue
    rows = np.array(rows)
    print(f"/reference {a}-{b} s against the same phase at 100-130 s ({len(rows)} samples): largest difference "
          f"q {rows[:, :nj].max():.1e} rad, q̇ {rows[:, nj:2 * nj].max():.1e} rad/s, "
          f"q̈ {rows[:, 2 * nj:3 * nj].max():.2f} rad/s², contacts {rows[:, 3 * nj:].max():.0f}; "
          f"q̈ differs by > 1e-3 at phases {sorted(jumps)}")
