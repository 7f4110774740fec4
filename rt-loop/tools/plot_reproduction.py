"""Felt force of the same simulated hand in a reproduction and a shadow recording.

Usage: python rt-loop/tools/plot_reproduction.py REPRO.parquet SHADOW.parquet OUT.png
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq

COLS = ["time", "position_x", "F_true", "F_pred"]


def load(path: str) -> dict[str, np.ndarray]:
    t = pq.read_table(path, columns=COLS)
    return {c: np.asarray(t.column(c)) for c in COLS}


def main(repro: str, shadow: str, out: str) -> None:
    r, s = load(repro), load(shadow)
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.8))
    ax[0].plot(s["time"], s["F_true"], lw=0.9, label="shadow: felt force on the simulated sponge")
    ax[0].plot(r["time"], r["F_true"], lw=0.9, label="reproduction: felt force on the virtual sponge")
    ax[0].plot(r["time"], r["F_pred"], lw=0.9, ls="--", label="reproduction: rendered F_pred")
    ax[0].set_xlabel("time [s]")
    ax[0].set_ylabel("force [N]")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(1000 * s["position_x"], s["F_true"], lw=0.9, label="shadow (simulated sponge)")
    ax[1].plot(1000 * r["position_x"], r["F_true"], lw=0.9, label="reproduction (virtual sponge)")
    ax[1].set_xlabel("depth x [mm]")
    ax[1].set_ylabel("felt force [N]")
    ax[1].legend(fontsize=8)
    ax[1].grid(alpha=0.3)
    fig.suptitle("same simulated hand (press-hold-release x3) on the real and on the virtual sponge", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    rms = float(np.sqrt(np.mean((r["F_true"] - r["F_pred"]) ** 2)))
    n = min(len(r["F_true"]), len(s["F_true"]))
    rms_rs = float(np.sqrt(np.mean((r["F_true"][:n] - s["F_true"][:n]) ** 2)))
    print(f"felt vs rendered rms {rms:.3f} N; felt reproduction vs shadow rms {rms_rs:.3f} N")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3])
