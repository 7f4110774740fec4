"""SYNTHETIC stand-in for a materials-testing machine: loading-unloading tests of a viscoelastic
elastomer, written as the CSV files such a machine exports (time, displacement, force, with
units in the headers), at several displacement rates.

There is no internet here but package registries, and no package on them was found shipping
real force-displacement loading-unloading data with a licence that allows a sample (see
docs/train.md), so the import, the manifest and the leave-one-rate-out evaluation are shown on
this model instead. It is labelled synthetic wherever it is used.

The material: Fung's quasi-linear viscoelasticity (QLV), the usual model of soft tissue and
elastomers: a nonlinear instantaneous elastic response F_e(x) = k1 x + k3 x^3 convolved with a
reduced relaxation function G(t) = g_inf + sum_i g_i exp(-t / tau_i) (a two-term Prony series),

    F = g_inf F_e(x) + q1 + q2,   dq_i/dt = -q_i / tau_i + g_i dF_e(x)/dt

integrated exactly per sample for a piecewise-linear F_e; driven by a triangular displacement
(load to `depth`, unload to 0). Its relaxing branches scale with the nonlinear F_e, so it is NOT
of the class of haptics-train's `prony` model (linear branches on the velocity). Contact is
unilateral (the force is clamped at 0: the probe leaves the surface when the relaxed material
lags behind). Measurement noise is Gaussian on the force.

    python -m haptics_train.viscoelastic --out data/elastomer
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv


@dataclass(frozen=True)
class Elastomer:
    k1: float = 0.12  # N/mm, instantaneous
    k3: float = 0.0008  # N/mm^3, instantaneous
    g_inf: float = 0.5  # G(infinity): the relaxed fraction
    g: tuple[float, ...] = (0.3, 0.2)  # Prony weights of G
    tau: tuple[float, ...] = (0.4, 4.0)  # s
    noise_n: float = 0.002  # force noise, N (sd)

    def elastic(self, x_mm: np.ndarray | float) -> np.ndarray | float:
        return self.k1 * x_mm + self.k3 * x_mm**3


#: displacement rates (mm/s) of the three tests, and of the validation tests: one slower and one
#: faster than all three, so that a choice made on them is a choice for extrapolation in rate
#: (a held-out rate at either end lies outside the training rates)
RATES_MM_S: tuple[float, ...] = (0.5, 2.0, 8.0)
VALIDATION_RATES_MM_S: tuple[float, ...] = (0.25, 16.0)


def triangle_knots(rate_mm_s: float, depth_mm: float = 10.0,
                   hold_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The corners of one loading-unloading cycle: times (s) and displacements (mm)."""
    ramp = depth_mm / rate_mm_s
    total = 2 * hold_s + 2 * ramp
    return (np.array([0, hold_s, hold_s + ramp, hold_s + 2 * ramp, total]),
            np.array([0, 0, depth_mm, 0, 0], dtype=float))  # fmt: skip


def triangle(rate_mm_s: float, depth_mm: float = 10.0, sample_hz: float = 50.0,
             hold_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The cycle's motion sampled at `sample_hz`: time (s), displacement (mm)."""
    kt, kx = triangle_knots(rate_mm_s, depth_mm, hold_s)
    t = np.arange(int(np.floor(kt[-1] * sample_hz)) + 1) / sample_hz
    return t, np.interp(t, kt, kx)


def loading_unloading(
    rate_mm_s: float,
    depth_mm: float = 10.0,
    sample_hz: float = 50.0,
    hold_s: float = 1.0,
    mat: Elastomer = Elastomer(),
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """One cycle: `hold_s` at rest, load at `rate_mm_s` to `depth_mm`, unload at the same
    rate, `hold_s` at rest. Returns time (s), displacement (mm), force (N)."""
    t, x = triangle(rate_mm_s, depth_mm, sample_hz, hold_s)
    fe = np.asarray(mat.elastic(x))
    q = np.zeros(len(mat.g))
    f = np.zeros(len(t))
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        rate = (fe[i] - fe[i - 1]) / dt
        for k, (g, tau) in enumerate(zip(mat.g, mat.tau, strict=True)):
            e = np.exp(-dt / tau)
            q[k] = q[k] * e + g * rate * tau * (1 - e)
        f[i] = mat.g_inf * fe[i] + q.sum()
    f = np.maximum(f, 0.0)
    rng = np.random.default_rng(seed)
    f = f + mat.noise_n * rng.standard_normal(len(f))
    return {"time": t, "displacement": x, "force": f}


def write_csv(path: str | Path, series: dict[str, np.ndarray]) -> Path:
    """As a testing machine exports it: `time [s]`, `displacement [mm]`, `force [N]`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pacsv.write_csv(pa.table({
        "time [s]": series["time"], "displacement [mm]": series["displacement"],
        "force [N]": series["force"],
    }), path)  # fmt: skip
    return path


def write_tests(out: str | Path, sample_hz: float = 50.0,
                rates: tuple[float, ...] | None = None) -> list[Path]:  # fmt: skip
    """The three rates plus the validation rates (or `rates`), one CSV each (seeds differ per
    file)."""
    out = Path(out)
    paths = []
    for i, r in enumerate(rates or (*RATES_MM_S, *VALIDATION_RATES_MM_S)):
        paths.append(write_csv(out / f"rate_{r:g}.csv",
                               loading_unloading(r, sample_hz=sample_hz, seed=i + 1)))  # fmt: skip
    return paths


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--out", default="data/elastomer")
    p.add_argument("--sample-hz", type=float, default=50.0)
    a = p.parse_args()
    for path in write_tests(a.out, a.sample_hz):
        print(path)


if __name__ == "__main__":
    main()
