"""The law-free stateful model (`lawfree`): learns an object whose law it does not share (a
Bouc-Wen hysteretic pad with a relaxing branch, not a foam) from presses alone, beats a
spring-damper on presses it was not fitted on, leaves the bench's friction out of what it
renders, and its ONNX graph steps in parity with `predict`."""

import copy
import json

import numpy as np
import pytest
from test_structured import RATE, info, presses  # the same presses and sequence info

from haptics_train.closed_loop import OnnxStepper
from haptics_train.contract import validate_model
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.models import TrainConfig, make_model
from haptics_train.reference import REFERENCE_KEY, check_reference, reference_entry

FRICTION_N = 0.4
SMALL = {"taus_s": [0.1, 1.0, 10.0], "play_frac": [0.02, 0.1]}


def pad(x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(object, measured = object + Coulomb friction): Bouc-Wen (n = 1) on a cubic spring
    plus a relaxing branch; in no model's class."""
    z = q = 0.0
    zmax, d = 0.002, np.exp(-1 / (RATE * 0.3))
    obj = np.zeros_like(x)
    for n in range(1, len(x)):
        e, de = max(x[n], 0.0), max(x[n], 0.0) - max(x[n - 1], 0.0)
        if e <= 0:
            z = q = 0.0
            continue
        dz = de * (1 - abs(z) / zmax * (0.6 * np.sign(z * de) + 0.4))
        z = float(np.clip(z + dz, -zmax, zmax))
        q = d * q + 150.0 * de
        obj[n] = max(0.0, 200 * e + 1.5e6 * e**3 + 400 * z + q)
    return obj, obj + FRICTION_N * np.tanh(v / 1e-4)


@pytest.fixture(scope="module")
def fitted():
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    m = make_model("lawfree", hyper=SMALL)
    m.fit([np.column_stack([x, v])], [y], info=[info(len(x))])
    return m


def test_lawfree_learns_a_law_it_does_not_share_and_renders_the_object_only(fitted):
    m = fitted
    sd = make_model("sd_poly2")
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    sd.fit(np.column_stack([x, v]), y)
    xt, vt = presses([0.018, 0.008], 1.3)  # depths and a rate it was not fitted on
    obj, yt = pad(xt, vt)
    X = np.column_stack([xt, vt])
    served = m.predict_served(X)
    assert np.all(served >= 0) and np.all(served[xt <= 0] == 0)
    rmse = float(np.sqrt(np.mean((m.predict(X) - yt) ** 2)))
    rmse_sd = float(np.sqrt(np.mean((sd.predict(X) - yt) ** 2)))
    assert rmse < 0.5 * rmse_sd, (rmse, rmse_sd)
    assert m.c_.sum() == pytest.approx(FRICTION_N, rel=0.35), m.c_
    assert np.sqrt(np.mean((served - obj) ** 2)) < 0.5 * rmse_sd


def test_lawfree_onnx_steps_in_parity(fitted, fused_ops):
    """The fused node (the default export) and the multi-node graph each match `predict`
    within 1e-4 N, and each other, stepped through ONNX Runtime."""
    m = fitted
    prov = provenance(m, TrainConfig(progress=False), None, None)
    om, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    meta = validate_model(om)
    assert meta["haptics.kind"] == "stateful"
    assert meta["haptics.state_size"] == str(m.state_size)
    ops = [n.op_type for n in om.graph.node]
    assert ops == ["LawFreeStep"], ops  # one fused node: the model-cost budget is p50 <= 5 us
    assert len(graph.graph.node) <= 40, [n.op_type for n in graph.graph.node]
    x, v = presses([0.02, 0.03], 2.0)  # past the deepest training press too (w = min(u, 1))
    X = np.column_stack([x, v])
    got, got_graph = (np.array([st.step(r) for r in X.astype(np.float32)])
                      for st in (OnnxStepper(om), OnnxStepper(graph)))  # fmt: skip
    ref = m.predict_served(X)
    np.testing.assert_allclose(got, ref, atol=1e-4)
    np.testing.assert_allclose(got_graph, ref, atol=1e-4)
    np.testing.assert_allclose(got, got_graph, atol=1e-4)


def test_lawfree_memory_holds_no_force_at_the_surface_and_exports_its_depth_functions(fitted):
    """A memory term's weight has no constant part (it vanishes with the compression: what is
    the same size at every depth is the bench's friction), the saturating depth functions are
    fitted, and the fused node carries their scales; `memory_at_surface` frees the constant."""
    m = fitted
    n = 2 + len(SMALL["taus_s"]) + len(SMALL["play_frac"])
    assert m.depth_scales_ == [0.1, 0.3]
    w = m.w_.reshape(3 + len(m.depth_scales_), n)
    assert np.all(w[0, 2:] == 0.0), w[0]
    assert np.any(w[3:, 2:] != 0.0) and np.any(w[0, :2] != 0.0)
    attrs = {a.name: list(a.floats) for a in m.to_onnx().graph.node[0].attribute if a.floats}
    assert attrs["readout_depth_scales"] == pytest.approx([0.1, 0.3])
    assert len(attrs["readout"]) == 5 * n
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    free = make_model("lawfree", hyper={**SMALL, "memory_at_surface": True})
    free.fit([np.column_stack([x, v])], [y], info=[info(len(x))])
    assert np.any(free.w_.reshape(5, n)[0, 2:] != 0.0)


def softening_pad(x: np.ndarray) -> np.ndarray:
    """An object that softens below the deepest press so far (a Mullins-type effect of filled
    rubbers and tissues): a stiffening spring times 1 - 0.5 (1 - exp(-(e_max - e) / 1 mm)).
    No fading memory reproduces it: the softening never recovers."""
    e = np.maximum(x, 0.0)
    top = np.maximum.accumulate(e)
    eta = 1.0 - 0.5 * (1.0 - np.exp(-(top - e) / 0.001))
    return np.where(e > 0, eta * (300 * e + 1.0e6 * e**3), 0.0)


def test_lawfree_irreversible_memory_learns_a_softening_and_steps_in_parity(fused_ops):
    """With `damage_frac`, `lawfree` carries the deepest compression so far (one more state)
    and saturating functions of the depth below it: on presses that grow then shrink, which
    it was not fitted on, it renders a softening object at least twice as close as without,
    and its fused node and multi-node graph step in parity with `predict`."""
    x, v = presses([0.006, 0.012, 0.009, 0.018, 0.01, 0.024, 0.015], 2.0)
    y = softening_pad(x)
    fits = {}
    for name, extra in {"without": {}, "with": {"damage_frac": [0.02, 0.05, 0.15]}}.items():
        m = make_model("lawfree", hyper={**SMALL, **extra})
        m.fit([np.column_stack([x, v])], [y], info=[info(len(x))])
        fits[name] = m
    m = fits["with"]
    assert m.state_size == len(SMALL["taus_s"]) + len(SMALL["play_frac"]) + 1
    assert fits["without"].state_size == m.state_size - 1
    xt, vt = presses([0.01, 0.02, 0.014, 0.022, 0.008, 0.016], 1.3)
    obj = softening_pad(xt)
    X = np.column_stack([xt, vt])
    err = {k: float(np.sqrt(np.mean((f.predict_served(X) - obj) ** 2))) for k, f in fits.items()}
    assert err["with"] < 0.5 * err["without"], err
    prov = provenance(m, TrainConfig(progress=False), None, None)
    om, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert validate_model(om)["haptics.state_size"] == str(m.state_size)
    attrs = {a.name: list(a.floats) for a in om.graph.node[0].attribute if a.floats}
    assert attrs["damage_frac"] == pytest.approx([0.02, 0.05, 0.15])
    assert len(graph.graph.node) <= 40, [n.op_type for n in graph.graph.node]
    got, got_graph = (np.array([st.step(r) for r in X.astype(np.float32)])
                      for st in (OnnxStepper(om), OnnxStepper(graph)))  # fmt: skip
    ref = m.predict_served(X)
    np.testing.assert_allclose(got, ref, atol=1e-4)
    np.testing.assert_allclose(got_graph, ref, atol=1e-4)


def eyring_pad(x: np.ndarray) -> np.ndarray:
    """A stiffening spring beside a Maxwell branch whose dashpot is an Eyring (sinh) one: the
    branch relaxes the faster the more force it holds (nonlinear viscoelasticity; the
    Hunt-Crossley object's memory). A readout linear in its weights cannot follow it."""
    s, dt = 0.0, 1 / RATE
    out = np.zeros_like(x)
    for n in range(1, len(x)):
        e, de = max(x[n], 0.0), max(x[n], 0.0) - max(x[n - 1], 0.0)
        if e <= 0:
            s = 0.0
            continue
        s += 2000.0 * de
        s = max(s - dt * 0.15 * np.sinh(s / 0.3), -2.0)
        out[n] = max(0.0, 300 * e + 1e6 * e**3 + s)
    return out


def test_lawfree_network_readout_follows_a_force_dependent_relaxation_and_steps_in_parity(
    fused_ops,
):
    """Read through a network chosen on validation presses (lawfree_net.py), `lawfree`'s own
    memory renders an Eyring-type object at least 1.3x closer than its linear readout on
    presses of rates and depths it was neither trained nor chosen on (measured 0.62-0.70x);
    the fused node and the multi-node graph step in parity with `predict`, the network alone
    (the linear readout exported as zeros) and on top of the linear readout alike."""
    import dataclasses

    from haptics_train.lawfree_selection import network_skipped
    from haptics_train.models.lawfree_net import fit_network_readout

    def rec(depths: list[float], period_s: float) -> tuple[np.ndarray, np.ndarray]:
        x, v = presses(depths, period_s)
        return np.column_stack([x, v]), eyring_pad(x)

    d = [0.01, 0.02, 0.015, 0.025, 0.006]
    train, valid = [rec(d, 2.0), rec(d[::-1], 0.7)], [rec(d[1:], 5.0), rec(d[:3], 0.4)]
    test = [rec([0.018, 0.008, 0.022], 1.2), rec([0.012, 0.024], 3.0)]
    X, y = [a for a, _ in train], [b for _, b in train]
    lin = make_model("lawfree", hyper=SMALL)
    lin.fit(X, y, info=[info(len(a)) for a in X])
    grid = (("alone", 16, 1e-3), ("residual", 16, 1e-3))
    net, scores = fit_network_readout(lin, X, y, [info(len(a)) for a in X],
                                      [(a, b, 1 / RATE) for a, b in valid], grid=grid,
                                      max_steps=3000)  # fmt: skip
    assert len(scores) == 2 and net.network is not None and lin.network is None
    # no friction in these recordings: `haptics-train train` tries the network on them
    assert network_skipped(lin) is None
    assert net.network.validation_rmse_n == pytest.approx(min(scores.values()))

    def err(m: object, recs: list) -> float:
        return float(np.sqrt(np.mean(np.concatenate([m.predict(a) - b for a, b in recs]) ** 2)))

    assert err(net, test) < err(lin, test) / 1.3, (err(net, test), err(lin, test))
    x, v = presses([0.02, 0.03], 2.0)  # past the deepest training press too (w = min(u, 1))
    Xs = np.column_stack([x, v])
    prov = provenance(net, TrainConfig(progress=False), None, None)
    for residual in (False, True):
        m = net
        m.net_ = dataclasses.replace(net.network, residual=residual)
        om, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
        assert [n.op_type for n in om.graph.node] == ["LawFreeStep"]
        attrs = {a.name: list(a.floats) for a in om.graph.node[0].attribute if a.floats}
        assert len(attrs["net_b1"]) == 16 and (any(attrs["readout"]) == residual)
        got, got_graph = (np.array([st.step(r) for r in Xs.astype(np.float32)])
                          for st in (OnnxStepper(om), OnnxStepper(graph)))  # fmt: skip
        ref = m.predict_served(Xs)
        assert np.ptp(ref) > 0.3  # a force that moves, so parity means something
        np.testing.assert_allclose(got, ref, atol=1e-4)
        np.testing.assert_allclose(got_graph, ref, atol=1e-4)
    # its reference steps (reference.py) catch a server that ignores the network's attributes,
    # as a build older than them does: the kernel without them is the linear readout alone
    om.metadata_props.add(key=REFERENCE_KEY, value=json.dumps(reference_entry(om, Xs[::40], "t")))
    assert check_reference(om) is None
    older = copy.deepcopy(om)
    node = older.graph.node[0]
    keep = [a for a in node.attribute if not a.name.startswith("net_")]
    del node.attribute[:]
    node.attribute.extend(keep)
    why = check_reference(older)
    assert why is not None and why.startswith(f"{REFERENCE_KEY}: step "), why


def test_lawfree_network_readout_is_not_tried_on_recordings_with_a_friction(fitted):
    """The pad's presses slide out of contact through the bench's Coulomb friction: the free
    air shows it, and a network would render it as the object's (docs/laws.md), so
    `haptics-train train` does not try one there (`lawfree_selection.network_skipped`)."""
    from haptics_train.lawfree_selection import network_skipped

    assert fitted.train_info_["free_air_friction_n"] == pytest.approx(FRICTION_N, rel=0.1)
    why = network_skipped(fitted)
    assert why is not None and "friction in free air" in why


def test_the_play_operators_follow_their_definition():
    """`plays` (a loop on Python floats, for speed) against the definition written as it reads,
    p = clamp(p, u - r, u + r) from p = 0, row by row with numpy: equal to the bit, on a random
    walk that crosses every band both ways, a zero width (p = u) included."""
    from haptics_train.models.lawfree import plays

    rng = np.random.default_rng(3)
    u = np.cumsum(rng.normal(scale=0.02, size=20_000))
    widths = np.array([0.0, 0.005, 0.05, 0.4])
    want = np.empty((len(u), len(widths)))
    p = np.zeros(len(widths))
    for n, un in enumerate(u):
        p = np.minimum(np.maximum(p, un - widths), un + widths)
        want[n] = p
    got = plays(u, widths)
    assert np.array_equal(got, want)
    assert np.array_equal(got[:, 0], u)  # no width: the play is the input itself
    assert plays(u[:0], widths).shape == (0, len(widths))
