"""The structured stateful model (`prony`) on imported loading-unloading tests of the
SYNTHETIC QLV elastomer: dissipative by construction, contract-valid, in parity with ONNX
Runtime, and ahead of the spring-damper on a held-out rate."""

import numpy as np
import pytest

from haptics_train.contract import validate_model
from haptics_train.export import onnx_predict, provenance, to_contract_onnx
from haptics_train.importer import import_series
from haptics_train.metrics import loop_work, regression_metrics
from haptics_train.models import TrainConfig, fit_recordings, make_model
from haptics_train.viscoelastic import write_tests

CFG = TrainConfig(progress=False)


@pytest.fixture(scope="module")
def tests(tmp_path_factory, rt_loop):
    d = tmp_path_factory.mktemp("qlv")
    return {
        c.stem: import_series(c, d / f"{c.stem}.parquet", "time", "displacement", "force",
                              rt_loop=str(rt_loop))
        for c in write_tests(d / "csv")
    }  # fmt: skip


def test_prony_is_dissipative_valid_and_beats_the_spring_damper(tests):
    train = [tests["rate_0.5"], tests["rate_8"]]
    held = tests["rate_2"]
    m = make_model("prony")
    fit_recordings(m, train, CFG)
    assert m.dt_ == pytest.approx(0.02) and m.kind == "stateful"
    assert np.all(m.w_ >= 0), m.w_  # every Maxwell branch dissipates
    sd = make_model("sd_poly2")
    fit_recordings(sd, train, CFG)
    y = held.target()
    p = m.predict(held.matrix(m.features))
    assert np.all(p >= 0)  # unilateral: it only pushes
    rmse = regression_metrics(y, p)["rmse"]
    rmse_sd = regression_metrics(y, sd.predict(held.matrix(sd.features)))["rmse"]
    assert rmse < 0.5 * rmse_sd, (rmse, rmse_sd)
    # a loading-unloading cycle dissipates energy in the model too (loop area > 0)
    assert loop_work(held.column("position_x"), p) > 0
    om = to_contract_onnx(m, provenance(m, CFG, None, None))
    meta = validate_model(om)
    assert meta["haptics.kind"] == "stateful" and meta["haptics.state_size"] == str(len(m.taus_))
    # imported 50 Hz rows, served by rt-loop at its default 10 kHz: the graph steps at 1e-4 s
    assert m.serve_dt_ == pytest.approx(1e-4) and meta["haptics.step_s"] == repr(1e-4)
    served = m.predict_served(held.matrix(m.features), dt=1e-4)
    np.testing.assert_allclose(onnx_predict(om, held, m.features), served, atol=1e-4)
