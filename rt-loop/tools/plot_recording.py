"""Plots one rt-loop recording: force vs time and force vs depth (hysteresis, permanent set).

Usage: python rt-loop/tools/plot_recording.py RECORDING.parquet OUT_PREFIX
Writes OUT_PREFIX-force-time.png and OUT_PREFIX-force-depth.png.
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq


def main(path: str, prefix: str) -> None:
    cols = ["time", "position_x", "rtob_force", "F_ref", "F_true", "cycle_no", "deformation"]
    t = pq.read_table(path, columns=cols)
    d = {c: np.asarray(t.column(c)) for c in cols}
    meta = pq.ParquetFile(path).metadata.metadata or {}
    title = path.split("/")[-1]
    if b"haptics.run" in meta:
        import json

        run = json.loads(meta[b"haptics.run"])
        title += f"  (ramp {run.get('ramp_rate')} N/s, seed {run.get('seed')})"
    step = max(1, len(d["time"]) // 200_000)
    sl = slice(None, None, step)

    fig, ax = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    ax[0].plot(d["time"][sl], d["F_ref"][sl], lw=0.8, label="F_ref (command)")
    ax[0].plot(d["time"][sl], d["rtob_force"][sl], lw=0.8, label="rtob_force (RFOB estimate)")
    ax[0].plot(d["time"][sl], d["F_true"][sl], lw=0.8, alpha=0.8, label="F_true (sim contact force)")
    ax[0].set_ylabel("force [N]")
    ax[0].legend(loc="upper left", fontsize=8)
    ax[0].set_title(title)
    ax[1].plot(d["time"][sl], 1000 * d["position_x"][sl], lw=0.8, label="depth x")
    ax[1].plot(d["time"][sl], 1000 * d["deformation"][sl], lw=1.2, label="deformation feature d(c-1)")
    ax[1].set_ylabel("depth [mm]")
    ax[1].set_xlabel("time [s]")
    ax[1].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(f"{prefix}-force-time.png", dpi=110)

    fig, ax = plt.subplots(figsize=(8, 6))
    cyc = d["cycle_no"]
    cmap = plt.get_cmap("viridis")
    n = int(cyc.max())
    for c in range(1, n + 1):
        m = cyc == c
        if m.sum() < 2:
            continue
        ax.plot(1000 * d["position_x"][m][::step], d["rtob_force"][m][::step], lw=0.8,
                color=cmap((c - 1) / max(1, n - 1)), label=f"cycle {c}" if c % 2 == 0 else None)
    ax.set_xlabel("depth x [mm]")
    ax.set_ylabel("rtob_force F_res [N]")
    ax.set_title("force vs depth: loading above unloading (hysteresis);\n"
                 "each loop starts deeper than the last (permanent set)", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(f"{prefix}-force-depth.png", dpi=110)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
