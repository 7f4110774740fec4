"""Overlays cycle 14 (F_max 14 N) of each dataset recording: the sponge's rate dependence.

Usage: python rt-loop/tools/plot_rates.py DATASET_DIR OUT.png
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq

NAMES = ["train_0.8", "train_1.8", "train_3.9", "train_6.2", "test_2.1"]


def main(dataset: str, out: str) -> None:
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for name in NAMES:
        t = pq.read_table(f"{dataset}/{name}.parquet", columns=["position_x", "cycle_no", "F_true"])
        m = np.asarray(t.column("cycle_no")) == 14
        x = np.asarray(t.column("position_x"))[m]
        f = np.asarray(t.column("F_true"))[m]
        s = max(1, int(m.sum()) // 20000)
        ax.plot(1000 * x[::s], f[::s], lw=0.9, label=f"{name} ({name.split('_')[1]} N/s)")
    ax.set_xlabel("depth x [mm]")
    ax.set_ylabel("F_true: sponge contact force [N]")
    ax.set_title("cycle 14 (F_max 14 N) at each ramp rate: rate dependence of the simulated sponge", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
