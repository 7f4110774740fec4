"""The study's figures (felt force over time and over depth, RMSE per model, position
replay), drawn from the runs' series and the scores; matplotlib is imported only here."""

from __future__ import annotations

from pathlib import Path

from .processes import Run
from .protocol import GOAL_RMSE
from .score import Row, rankable, repro_rmse, sd2_row


def write_plots(out: Path, ref: Run, rows: list[Row], rec: dict, rep: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ranked = sorted((r for r in rows if r.learned and rankable(r)), key=repro_rmse)
    show = ranked[:3]
    sd2 = sd2_row(rows)
    if sd2 is not None and sd2.run.series:
        show.append(sd2)
    rs = ref.series
    fig, ax = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    ax[0].plot(rs["time"], rs["F_true"], "k", lw=1.6, label="simulated object (reference)")
    for r in show:
        s = r.run.series
        ax[0].plot(s["time"], s["F_true"], lw=0.9, label=f"{r.name} (RMSE {r.repro['rmse']:.2f} N)")  # type: ignore[index]
    ax[0].set_ylabel("felt force F_true [N]")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(rs["time"], 1000 * rs["position_x"], "k", lw=1.6, label="simulated object")
    for r in show:
        s = r.run.series
        ax[1].plot(s["time"], 1000 * s["position_x"], lw=0.9, label=r.name)
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("depth x [mm]")
    ax[1].grid(alpha=0.3)
    fig.suptitle(
        "the same simulated hand on the simulated object and on virtual objects", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(out / "felt_force_time.png", dpi=90)
    plt.close(fig)

    n = len(show)
    fig, ax = plt.subplots(1, max(n, 1), figsize=(4.2 * max(n, 1), 4), sharey=True, squeeze=False)
    for i, r in enumerate(show):
        a = ax[0][i]
        a.plot(1000 * rs["position_x"], rs["F_true"], "k", lw=1.2, label="simulated object")
        s = r.run.series
        a.plot(1000 * s["position_x"], s["F_true"], "tab:red", lw=0.9, label=r.name)
        a.set_xlabel("depth x [mm]")
        a.set_title(r.name, fontsize=9)
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    ax[0][0].set_ylabel("felt force F_true [N]")
    fig.tight_layout()
    fig.savefig(out / "felt_force_depth.png", dpi=90)
    plt.close(fig)

    ok = sorted((r for r in rows if r.repro is not None), key=repro_rmse)
    fig, ax = plt.subplots(figsize=(10, 4))
    names = [r.name.replace("rt-loop builtin spring-damper", "builtin sd") for r in ok]
    vals = [min(r.repro["rmse"], 10.0) for r in ok]  # type: ignore[index]
    colors = ["tab:blue" if r.learned else "tab:gray" for r in ok]
    ax.bar(names, vals, color=colors)
    ax.axhline(GOAL_RMSE, color="tab:red", ls="--", lw=1, label="thesis RF 1.21 N")
    ax.set_ylabel("felt-force RMSE vs simulated object [N]")
    ax.tick_params(axis="x", rotation=60, labelsize=8)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "rmse.png", dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    ax[0].plot(rec["time"], rec["rtob_force"], "k", lw=1.0, label="recording (force control)")
    ax[0].plot(
        rep["time"],
        rep["rtob_force"],
        "tab:red",
        lw=0.7,
        label="position replay on the simulated object",
    )
    ax[0].set_ylabel("force response F_res [N]")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(rec["time"], 1000 * rec["position_x"], "k", lw=1.0, label="recording")
    ax[1].plot(rep["time"], 1000 * rep["position_x"], "tab:red", lw=0.7, label="replay")
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("depth x [mm]")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "position_replay.png", dpi=80)
    plt.close(fig)
