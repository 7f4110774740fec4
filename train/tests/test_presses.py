"""The press-and-hold programme of `train_hold` (presses.py) and its command."""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from haptics_train.cli import main
from haptics_train.presses import (
    CLEAR_M,
    DEPTH_FRACTIONS,
    SPEEDS_MPS,
    press_hold_trajectory,
    ramp_depth_m,
)


def _presses(x: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) indices of each stretch in contact (x > 0)."""
    inside = np.concatenate([[False], x > 0.0, [False]])
    edges = np.flatnonzero(np.diff(inside.astype(int)))
    return list(zip(edges[::2], edges[1::2], strict=True))


def test_every_depth_at_every_speed_once_with_holds():
    depth = 0.03
    t, x = press_hold_trajectory(depth, seed=5, step_s=1e-3)
    assert np.all(np.diff(t) > 0) and np.isfinite(x).all()
    assert x[0] == CLEAR_M and x[-1] == CLEAR_M
    presses = _presses(x)
    assert len(presses) == len(DEPTH_FRACTIONS) * len(SPEEDS_MPS)
    peaks = sorted(round(float(x[a:b].max()) / depth, 6) for a, b in presses)
    assert peaks == sorted(round(f, 6) for f in DEPTH_FRACTIONS for _ in SPEEDS_MPS)
    speeds = []
    for a, b in presses:
        top = x[a:b].max()
        held = np.flatnonzero(x[a:b] == top)
        assert held.size * 1e-3 >= 1.5  # a hold of at least 1.5 s at the press's depth
        v = np.diff(x[a:b]) / 1e-3
        speeds.append(float(np.abs(v).max()))
    # three peak speeds, each at every depth
    for s in SPEEDS_MPS:
        assert sum(abs(p - s) < 0.05 * s for p in speeds) == len(DEPTH_FRACTIONS)


def test_the_order_follows_the_seed():
    _, a = press_hold_trajectory(0.02, seed=1)
    _, b = press_hold_trajectory(0.02, seed=1)
    _, c = press_hold_trajectory(0.02, seed=2)
    assert np.array_equal(a, b)
    assert a.shape != c.shape or not np.array_equal(a, c)


@pytest.mark.parametrize("bad", [0.0, -0.01, float("nan"), 30.0])
def test_a_depth_that_is_not_a_compression_in_metres_is_refused(bad):
    with pytest.raises(ValueError, match="depth"):
        press_hold_trajectory(bad)


def _ramp(path: Path, x_max: float) -> None:
    x = np.linspace(-0.001, x_max, 50)
    pq.write_table(pa.table({"time": np.arange(50) * 0.01, "position_x": x}), path)


def test_the_command_scales_by_the_ramps_not_the_air_or_hold(tmp_path, capsys):
    ds = tmp_path / "ds"
    ds.mkdir()
    _ramp(ds / "train_0.8.parquet", 0.021)
    _ramp(ds / "train_6.2.parquet", 0.024)
    _ramp(ds / "train_air.parquet", 0.5)  # never the scale: not a ramp
    _ramp(ds / "train_hold.parquet", 0.9)
    assert ramp_depth_m(ds) == pytest.approx(0.024)
    out = tmp_path / "presses.parquet"
    main(["presses", "--dataset", str(ds), "--out", str(out)])
    assert "24.00 mm" in capsys.readouterr().out
    tab = pq.read_table(out)
    assert tab.column_names == ["time", "position_x"]
    x = tab.column("position_x").to_numpy()
    assert x.max() == pytest.approx(0.95 * 0.024)


def test_the_command_without_ramps_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "ds").mkdir()
    with pytest.raises(SystemExit) as e:
        main(["presses", "--dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "o.parquet")])
    assert e.value.code == 2
    assert "no train_*.parquet ramp recording" in capsys.readouterr().err
