"""An example ONNX object (docs/laws/onnx.md): Hunt-Crossley contact with a nonlinear
(Eyring) Maxwell memory, a law no model of haptics_train shares.

Sources:
- K. H. Hunt, F. R. E. Crossley, "Coefficient of restitution interpreted as damping in
  vibroimpact", J. Appl. Mech. 42(2):440-445, 1975: a Hertzian contact force k e^n whose
  damping grows with the penetration, lambda e^n de/dt, so the force is continuous at contact
  and never sticks at separation;
- D. W. Marhefka, D. E. Orin, "A compliant contact model with nonlinear damping for simulation
  of robotic systems", IEEE Trans. SMC-A 29(6):566-572, 1999: lambda = 3/2 alpha k;
- H. Eyring, "Viscosity, plasticity, and diffusion as examples of absolute reaction rates",
  J. Chem. Phys. 4:283-291, 1936 (and T. Ree, H. Eyring, J. Appl. Phys. 26:793, 1955): a
  dashpot whose flow rate is a sinh of its stress, the standard nonlinear element of polymer
  viscoelasticity; in series with a spring it is a Maxwell branch whose relaxation speeds up
  exponentially with the stress it carries (a logarithmic rate dependence, unlike the linear
  Maxwell branches of `structured` and `prony`).

The law, with e = max(x, 0) the compression (m), v the velocity (m/s), E = e^n, stepped at
`RATE_HZ` (dt = 1/RATE_HZ, explicit, the order below):

    q1 = q + g k (E - E_prev)                                   the branch loads with E
    r  = dt (q0 / tau) sinh(q1 / q0)                            Eyring flow over one step
    q  = sign(q1) max(|q1| - |r|, 0)                            relaxation never crosses 0
    F  = [e > 0] max(0, k E + lambda E v + q)                   N, pushes only, 0 out of contact

State: (q, E_prev), carried as the stateful contract's `h` ([1, 1, 2]); `c` ([1, 1, 2]) passes
through unused. Inputs `features` = (position_x, velocity), output `force` [1, 1].

`python -m haptics_train.objects.hunt_crossley` writes `materials/hunt-crossley.onnx` and the
reference trajectory rt-loop's tests compare with
(`rt-loop/tests/fixtures/hunt-crossley-reference.csv`).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import onnx

from haptics_train.models.onnx_graph import Graph, stateful_model
from haptics_train.reference import entry_of, press_rows, write_entry

#: how often the bench steps the graph (the material file's `rate_hz`): once per control period
RATE_HZ = 10_000.0
#: the reference programme's knots: every 2 ms, linear in between
KNOT_S = 0.002
STATE = 2


@dataclass(frozen=True)
class HuntCrossley:
    """The law's constants (N, m, s)."""

    k: float = 3000.0  # N / m^n: 5.5 N at 15 mm
    n: float = 1.5  # Hertz's exponent for a sphere on a flat
    alpha: float = 1.5  # s/m, Hunt-Crossley damping factor (lambda = 3/2 alpha k)
    g: float = 0.6  # the Maxwell branch's stiffness, a fraction of k
    q0: float = 0.5  # N, the Eyring dashpot's stress scale
    tau: float = 0.4  # s, its relaxation time at small stress

    @property
    def lam(self) -> float:
        return 1.5 * self.alpha * self.k


def step(p: HuntCrossley, state: np.ndarray, x: float, v: float, dt: float) -> float:
    """One step of the law in float64 (the reference); updates `state` = (q, E_prev)."""
    e = max(x, 0.0)
    big_e = e**p.n
    q1 = state[0] + p.g * p.k * (big_e - state[1])
    r = dt * (p.q0 / p.tau) * np.sinh(q1 / p.q0)
    q = float(np.sign(q1) * max(abs(q1) - abs(r), 0.0))
    state[0], state[1] = q, big_e
    if e <= 0.0:
        return 0.0
    return max(0.0, p.k * big_e + p.lam * big_e * v + q)


def build(p: HuntCrossley, rate_hz: float = RATE_HZ) -> onnx.ModelProto:
    """The law as a stateful graph (docs/model-contract.md's shapes, docs/laws/onnx.md)."""
    dt = 1.0 / rate_hz
    g = Graph("hunt_crossley_eyring")
    x, v = g.split("features", [1, 1], axis=1, hint="kin")  # [1, 1] each
    q, e_prev = g.split("h_in", [1, 1], axis=2, hint="state")  # [1, 1, 1] each
    e = g.op("Relu", x, hint="e")
    big_e = g.op("Pow", e, g.const(p.n, "n"), hint="E")
    d_e = g.op("Sub", big_e, e_prev, hint="dE")
    q1 = g.op("Add", q, g.op("Mul", d_e, g.const(p.g * p.k, "gk")), hint="q1")
    r = g.op("Mul", g.op("Sinh", g.op("Div", q1, g.const(p.q0, "q0"))),
             g.const(dt * p.q0 / p.tau, "flow"), hint="r")  # fmt: skip
    shrunk = g.op("Relu", g.op("Sub", g.op("Abs", q1), g.op("Abs", r)))
    q2 = g.op("Mul", g.op("Sign", q1), shrunk, hint="q")
    elastic = g.op("Mul", big_e, g.const(p.k, "k"))
    damping = g.op("Mul", g.op("Mul", big_e, v), g.const(p.lam, "lam"))
    total = g.op("Add", g.op("Add", elastic, damping), q2, hint="total")
    force = g.op("Mul", g.op("Relu", total), g.op("Sign", e), hint="force")
    big_e3 = g.op("Reshape", big_e, g.ints([1, 1, 1], "e_shape"))
    h_out = g.op("Concat", q2, big_e3, axis=2, hint="h")
    m = stateful_model(g, 2, STATE, force, h_out)
    provenance = {
        "model": "hunt_crossley_eyring",
        "law": "Hunt & Crossley 1975 contact with an Eyring (1936) nonlinear Maxwell branch",
        "constants": asdict(p),
        "rate_hz": rate_hz,
        "written_by": "haptics_train.objects.hunt_crossley",
    }
    for key, value in {
        "haptics.features": "position_x,velocity",
        "haptics.kind": "stateful",
        "haptics.units": "N",
        "haptics.state_size": str(STATE),
        "haptics.provenance": json.dumps(provenance, sort_keys=True),
    }.items():
        m.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    write_entry(m, law_reference(p, rate_hz))
    onnx.checker.check_model(m)
    return m


def law_reference(p: HuntCrossley, rate_hz: float = RATE_HZ) -> dict:
    """The graph's reference steps (`haptics.reference`, docs/model-contract.md): a press to
    15 mm and back (`reference.press_rows`), one row per step from the zero state, with the
    force the law computes in float64. Why the law and not ONNX Runtime: the entry then binds
    the graph to the law it stands for on whatever machine opens it (rt-loop and infer-server
    check it at load), and the committed file does not depend on the last bit of this machine's
    `Sinh`; the graph is within 2e-6 N of the law, far inside the tolerance."""
    rows = press_rows(("position_x", "velocity"))
    state = np.zeros(STATE)
    force = [step(p, state, float(x), float(v), 1.0 / rate_hz) for x, v in rows.astype(float)]
    return entry_of(rows, force, "the law in float64 (haptics_train.objects.hunt_crossley), "
                    "a press to 15 mm and back")


def programme_knots() -> tuple[np.ndarray, np.ndarray]:
    """The reference pressing programme, sampled every `KNOT_S` (2.4 s): a slow press to 12 mm
    and a hold (relaxation), a partial release and hold, a fast press to 15 mm, a separation,
    then a 3 Hz oscillation about 8 mm."""
    t = np.round(np.arange(0.0, 2.4 + KNOT_S / 2, KNOT_S), 6)
    ramps = np.interp(
        t,
        [0.0, 0.05, 0.5, 0.9, 1.0, 1.2, 1.3, 1.45, 1.6],
        [-0.001, -0.001, 0.012, 0.012, 0.004, 0.004, 0.015, -0.002, -0.002],
    )
    osc = 0.008 - 0.01 * np.cos(2.0 * np.pi * 3.0 * (t - 1.6))
    x = np.where(t <= 1.6, ramps, np.minimum(osc, 0.013))
    return t, x


def reference(p: HuntCrossley, rate_hz: float = RATE_HZ) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:  # fmt: skip
    """The law stepped at `rate_hz` along the programme (x linear between the knots, v the
    change in x over one step, 0 at the first), the force at every step: (t, x, force)."""
    kt, kx = programme_knots()
    per = round(KNOT_S * rate_hz)
    n = (len(kt) - 1) * per + 1
    # x at step j: between knots i and i+1 at fraction (j - i per) / per, as rt-loop's test
    i = np.minimum(np.arange(n) // per, len(kt) - 2)
    frac = (np.arange(n) - i * per) / per
    x = kx[i] + (kx[i + 1] - kx[i]) * frac
    t = np.arange(n) / rate_hz
    dt = 1.0 / rate_hz
    state = np.zeros(STATE)
    force = np.empty(n)
    for j in range(n):
        v = 0.0 if j == 0 else (x[j] - x[j - 1]) / dt
        force[j] = step(p, state, float(x[j]), v, dt)
    return t, x, force


def write_reference(path: Path, p: HuntCrossley) -> None:
    """The force at every knot (every `KNOT_S`), with the knot's position, as CSV."""
    t, x, force = reference(p)
    per = round(KNOT_S * RATE_HZ)
    lines = ["t_s,x_m,force_n"]
    lines += [
        f"{float(t[j])!r},{float(x[j])!r},{float(force[j]):.9g}" for j in range(0, len(t), per)
    ]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--onnx", type=Path, default=Path("materials/hunt-crossley.onnx"))
    ap.add_argument(
        "--reference", type=Path,
        default=Path("rt-loop/tests/fixtures/hunt-crossley-reference.csv"),
    )  # fmt: skip
    a = ap.parse_args(argv)
    p = HuntCrossley()
    a.onnx.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(build(p), a.onnx)
    a.reference.parent.mkdir(parents=True, exist_ok=True)
    write_reference(a.reference, p)
    print(f"wrote {a.onnx} and {a.reference}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
