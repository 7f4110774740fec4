"""SYNTHETIC loading-unloading tests of the bench's OWN object laws, written as a testing
machine exports them (`time [s]`, `displacement [mm]`, `force [N]`), for the
leave-one-rate-out study (`haptics_train.loro --generator bouc-wen|gel|hunt-crossley`).

The force is not computed here: the motion (the same triangular cycles as the QLV elastomer of
`viscoelastic`, at the same rates) is handed to `rt-loop object-force`, which steps a fresh
object of the material file (materials/*.toml: Bouc-Wen, the poroelastic gel, the ONNX
Hunt-Crossley contact) along it exactly as the study's oracle does, at the bench's 10 kHz with
its sub-steps. So the tests come from the laws the bench renders, not from a copy of them. The
corners of the cycle are given to rt-loop as rows of their own (the motion is then exact, not
the 50 Hz samples' interpolation), and only the 50 Hz rows are kept. Gaussian force noise is
added as the QLV generator adds it.

    python -m haptics_train.bench_tests --material materials/gel.toml --out data/loro-gel/csv
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv

from .importer import find_rt_loop
from .viscoelastic import RATES_MM_S, VALIDATION_RATES_MM_S, triangle, triangle_knots, write_csv

#: the repository's material files
MATERIALS = Path(__file__).resolve().parents[3] / "materials"

#: force noise, N (sd): the QLV elastomer's (`viscoelastic.Elastomer.noise_n`)
NOISE_N = 0.002


class ObjectForceError(RuntimeError):
    """`rt-loop object-force` refused the material or the motion (its one-line message)."""


def drive(material: Path, t_s: np.ndarray, x_m: np.ndarray,
          rt_loop: str | None = None) -> np.ndarray:  # fmt: skip
    """The force (N) of a fresh object of `material` driven along (t_s, x_m), one per row,
    computed by `rt-loop object-force` (the oracle's stepping)."""
    exe = find_rt_loop(rt_loop)
    with tempfile.TemporaryDirectory(prefix="object-force-") as d:
        src, dst = Path(d) / "motion.csv", Path(d) / "force.csv"
        np.savetxt(src, np.column_stack([t_s, x_m]), delimiter=",", header="t_s,x_m",
                   comments="", fmt="%.17g")  # fmt: skip
        cmd = [str(exe), "object-force", "--material", str(material), "--input", str(src),
               "--out", str(dst)]  # fmt: skip
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            msg = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise ObjectForceError(f"rt-loop object-force on {material}: {msg}")
        return pacsv.read_csv(dst).column("force_n").to_numpy()


def loading_unloading(
    material: Path, rate_mm_s: float, depth_mm: float = 10.0, sample_hz: float = 50.0,
    hold_s: float = 1.0, noise_n: float = NOISE_N, seed: int = 0, rt_loop: str | None = None,
) -> dict[str, np.ndarray]:  # fmt: skip
    """One cycle of the material's object (as `viscoelastic.loading_unloading`): time (s),
    displacement (mm), force (N, with noise)."""
    t, x = triangle(rate_mm_s, depth_mm, sample_hz, hold_s)
    kt, kx = triangle_knots(rate_mm_s, depth_mm, hold_s)
    extra = kt[~np.isin(kt, t)]
    tt = np.concatenate([t, extra])
    order = np.argsort(tt, kind="stable")
    tt = tt[order]
    keep = order < len(t)
    f = drive(material, tt, np.interp(tt, kt, kx) * 1e-3, rt_loop)[keep]
    rng = np.random.default_rng(seed)
    return {"time": t, "displacement": x, "force": f + noise_n * rng.standard_normal(len(f))}


def write_tests(material: Path, out: str | Path, sample_hz: float = 50.0,
                rt_loop: str | None = None, rates: tuple[float, ...] | None = None,
                ) -> list[Path]:  # fmt: skip
    """The three rates plus the validation rates (or `rates`), one CSV each (seeds as the QLV
    generator's)."""
    out = Path(out)
    paths = []
    for i, r in enumerate(rates or (*RATES_MM_S, *VALIDATION_RATES_MM_S)):
        s = loading_unloading(material, r, sample_hz=sample_hz, seed=i + 1, rt_loop=rt_loop)
        paths.append(write_csv(out / f"rate_{r:g}.csv", s))
    return paths


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--material", required=True, help="a material file (materials/*.toml)")
    p.add_argument("--out", required=True)
    p.add_argument("--sample-hz", type=float, default=50.0)
    p.add_argument("--rt-loop", help="rt-loop binary (else $HAPTICS_RT_LOOP, target/release)")
    a = p.parse_args()
    for path in write_tests(Path(a.material), a.out, a.sample_hz, a.rt_loop):
        print(path)


if __name__ == "__main__":
    main()
