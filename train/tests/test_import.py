import os
import stat
import sys
import textwrap

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest

from haptics_train.closed_loop import replay_features
from haptics_train.data import DataError
from haptics_train.importer import RtLoopMissing, find_rt_loop, import_series
from haptics_train.synthetic import make_recording_columns, write_recording


def _series_csv(path, n=4000):
    t = np.arange(n) * 1e-3  # 1 kHz device, time in ms below
    x_mm = 10.0 * np.sin(np.pi * t / t[-1]) ** 2
    f = 0.8 * x_mm + 0.01 * x_mm**2
    pacsv.write_csv(pa.table({"t_ms": t * 1e3, "disp_mm": x_mm, "load_N": f}), path)
    return t, x_mm, f


def test_missing_binary_gives_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("HAPTICS_RT_LOOP", str(tmp_path / "nope"))
    with pytest.raises(RtLoopMissing, match="HAPTICS_RT_LOOP"):
        find_rt_loop()
    with pytest.raises(RtLoopMissing, match="--rt-loop"):
        find_rt_loop(str(tmp_path / "also-nope"))


def test_bad_input_is_refused_before_running_anything(tmp_path):
    csv = tmp_path / "s.csv"
    _series_csv(csv)
    with pytest.raises(DataError, match="no column"):
        import_series(csv, tmp_path / "o.parquet", "t_ms", "nope", "load_N", "ms", "mm")
    with pytest.raises(DataError, match="must end in .parquet"):
        import_series(csv, tmp_path / "o.txt", "t_ms", "disp_mm", "load_N", "ms", "mm")
    with pytest.raises(DataError, match="no such input"):
        import_series(tmp_path / "x.csv", tmp_path / "o.parquet", "a", "b", "c")
    with pytest.raises(DataError, match="time-unit"):
        import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", "h", "mm")


def test_arguments_reach_rt_loop_features(tmp_path):
    """A stand-in rt-loop records its argv and writes a recording: checks the hand-over."""
    log = tmp_path / "argv.txt"
    fake = tmp_path / "rt-loop"
    fake.write_text(
        textwrap.dedent(f"""\
        #!{sys.executable}
        import sys
        from haptics_train.synthetic import write_recording
        open({str(log)!r}, "w").write("\\n".join(sys.argv[1:]))
        write_recording(sys.argv[sys.argv.index("--out") + 1], ramp_rate=6.2, cycles=1)
    """)
    )
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    csv = tmp_path / "s.csv"
    _series_csv(csv)
    rec = import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", "ms", "mm",
                        rt_loop=str(fake))  # fmt: skip
    argv = log.read_text().split("\n")
    assert argv[0] == "features"
    pairs = dict(zip(argv[1::2], argv[2::2], strict=False))
    assert pairs["--time-col"] == "t_ms" and pairs["--time-unit"] == "ms"
    assert pairs["--position-col"] == "disp_mm" and pairs["--position-unit"] == "mm"
    assert pairs["--force-col"] == "load_N" and pairs["--input"] == str(csv)
    assert len(rec) > 0


def test_failing_rt_loop_reports_its_stderr(tmp_path):
    fake = tmp_path / "rt-loop"
    fake.write_text("#!/bin/sh\necho 'bad time column' >&2\nexit 3\n")
    fake.chmod(0o755)
    csv = tmp_path / "s.csv"
    _series_csv(csv)
    with pytest.raises(RuntimeError, match="bad time column"):
        import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", "ms", "mm",
                      rt_loop=str(fake))  # fmt: skip


def test_real_import_through_rt_loop(tmp_path, rt_loop):
    csv = tmp_path / "s.csv"
    t, x_mm, f = _series_csv(csv)
    rec = import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", "ms", "mm",
                        rt_loop=str(rt_loop))  # fmt: skip
    assert len(rec) == len(t)
    np.testing.assert_allclose(rec.column("position_x"), x_mm * 1e-3, atol=1e-9)
    np.testing.assert_allclose(rec.column("rtob_force"), f, atol=1e-9)
    np.testing.assert_allclose(rec.column("time"), t, atol=1e-9)
    # the features rt-loop computed follow the very rules the closed loop replays
    rf = replay_features(rec, rec.column("rtob_force"))
    for k in ("f_previous_x", "f_previous_v", "f_previous_a", "cycle_no", "deformation"):
        np.testing.assert_allclose(rf[k], rec.column(k), rtol=1e-12, err_msg=k)


def test_synthetic_writer_round_trips(tmp_path):
    p = write_recording(tmp_path / "r.parquet", ramp_rate=6.2, cycles=1)
    cols = make_recording_columns(ramp_rate=6.2, cycles=1)
    from haptics_train.data import load_recording

    rec = load_recording(p)
    np.testing.assert_array_equal(rec.column("rtob_force"), cols["rtob_force"])
    assert rec.meta["haptics.run"]["ramp_rate"] == 6.2
    assert os.path.getsize(p) > 0
