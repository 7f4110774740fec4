import json
import os
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from haptics_train.closed_loop import contact_thresholds, replay_features
from haptics_train.data import DataError
from haptics_train.features import NINE
from haptics_train.import_fixtures import CASES, cycle, run_case
from haptics_train.importer import (
    FORCE_UNITS,
    POSITION_UNITS,
    TIME_UNITS,
    RtLoopMissing,
    describe_import,
    find_rt_loop,
    import_series,
)
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
        import_series(csv, tmp_path / "o.parquet", "t_ms", "nope", "load_N", time_unit="ms",
                      position_unit="mm")  # fmt: skip
    with pytest.raises(DataError, match="must end in .parquet"):
        import_series(csv, tmp_path / "o.txt", "t_ms", "disp_mm", "load_N", time_unit="ms")
    with pytest.raises(DataError, match="no such input"):
        import_series(tmp_path / "x.csv", tmp_path / "o.parquet", "a", "b", "c")
    with pytest.raises(DataError, match="time-unit"):
        import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", time_unit="h")


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
    rec = import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", time_unit="ms",
                        position_unit="mm", force_unit="mN", rt_loop=str(fake), g_v=7.0,
                        g_a=9.0, contact_on_n=0.2, contact_off_n=0.1)  # fmt: skip
    argv = log.read_text().split("\n")
    assert argv[0] == "features"
    pairs = dict(zip(argv[1::2], argv[2::2], strict=False))
    # the series reaches rt-loop converted to SI, the units in its headers
    assert pairs["--time-col"] == "time [s]" and pairs["--position-col"] == "position [m]"
    assert pairs["--force-col"] == "force [N]"
    assert (pairs["--g-v"], pairs["--g-a"]) == ("7.0", "9.0")
    assert (pairs["--contact-on-n"], pairs["--contact-off-n"]) == ("0.2", "0.1")
    pre = json.loads(pairs["--meta-json"])
    assert pre["source"] == str(csv.resolve())
    assert pre["units"]["force"] == {"unit": "mN", "from": "option", "column": "load_N"}
    assert pre["units"]["time"]["unit"] == "ms" and pre["units"]["position"]["unit"] == "mm"
    assert len(rec) > 0


def test_failing_rt_loop_reports_its_stderr(tmp_path):
    fake = tmp_path / "rt-loop"
    fake.write_text("#!/bin/sh\necho 'bad time column' >&2\nexit 3\n")
    fake.chmod(0o755)
    csv = tmp_path / "s.csv"
    _series_csv(csv)
    with pytest.raises(RuntimeError, match="bad time column"):
        import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", time_unit="ms",
                      position_unit="mm", rt_loop=str(fake))  # fmt: skip


def test_real_import_through_rt_loop(tmp_path, rt_loop):
    csv = tmp_path / "s.csv"
    t, x_mm, f = _series_csv(csv)
    rec = import_series(csv, tmp_path / "o.parquet", "t_ms", "disp_mm", "load_N", time_unit="ms",
                        position_unit="mm", rt_loop=str(rt_loop))  # fmt: skip
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


# --- external-looking fixtures (haptics_train.import_fixtures), through the real rt-loop ---


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_fixture_is_imported_or_refused_with_its_reason(case, tmp_path, rt_loop):
    status, res = run_case(case, tmp_path, str(rt_loop))
    if case.refused is None:
        assert status == "ok", res
        assert np.isfinite(res.matrix(NINE)).all()
    else:
        assert status == "refused" and case.refused in str(res), res


def _import(tmp_path, rt_loop, cols, **kw):
    src = tmp_path / "in.csv"
    pacsv.write_csv(pa.table(cols), src)
    names = list(cols)
    kw.setdefault("overwrite", True)  # several imports per test into the same scratch file
    return import_series(src, tmp_path / "out.parquet", *names, rt_loop=str(rt_loop), **kw)


UNIT_OPTIONS = [("time", u) for u in TIME_UNITS] + [("position", u) for u in POSITION_UNITS] + [
    ("force", u) for u in FORCE_UNITS
]


@pytest.mark.parametrize(("what", "unit"), UNIT_OPTIONS, ids=[f"{w}-{u}" for w, u in UNIT_OPTIONS])
def test_every_unit_option_is_honoured(what, unit, tmp_path, rt_loop):
    """The same physical cycle written in `unit` (plain headers) comes out in SI."""
    c = cycle()
    si = {"time": c["time"], "position": 1e-3 * c["displacement"], "force": c["force"]}
    table = {"time": TIME_UNITS, "position": POSITION_UNITS, "force": FORCE_UNITS}[what]
    cols = {k: v / table[unit] if k == what else v for k, v in si.items()}
    rec = _import(tmp_path, rt_loop, cols, **{f"{what}_unit": unit})
    for k, col in (("time", "time"), ("position", "position_x"), ("force", "rtob_force")):
        np.testing.assert_allclose(rec.column(col), si[k] - (si[k][0] if k == "time" else 0),
                                   rtol=1e-9, atol=1e-12, err_msg=f"{k} ({what} in {unit})")
    units = rec.meta["haptics.run"]["units"]
    assert units[what] == {"unit": unit, "from": "option", "column": what}


def test_header_units_and_metadata(tmp_path, rt_loop):
    c = cycle()
    rec = _import(tmp_path, rt_loop, {"t [ms]": 1e3 * c["time"], "x (mm)": c["displacement"],
                                      "F [mN]": 1e3 * c["force"]})  # fmt: skip
    np.testing.assert_allclose(rec.column("rtob_force"), c["force"], rtol=1e-12)
    np.testing.assert_allclose(rec.column("position_x"), 1e-3 * c["displacement"], rtol=1e-12)
    run = rec.meta["haptics.run"]
    assert {k: v["from"] for k, v in run["units"].items()} == dict.fromkeys(
        ("time", "position", "force"), "header")
    assert run["units"]["force"]["unit"] == "mN"
    assert run["source"].endswith("in.csv") and len(run["preprocessing"]["source_sha256"]) == 64
    assert run["timing"]["sample_rate_hz"] == pytest.approx(50.0)
    # gains derived from the rate (g dt = 0.2), contact from the force's noise floor
    assert run["filters"]["g_v"] == pytest.approx(10.0) and run["filters"]["g_v_from"] == "derived"
    assert run["filters"]["g_a_dt"] <= 1.0
    assert run["contact"]["from"] == "noise_floor"
    assert 0.001 < run["contact"]["force_noise_floor_n"] < 0.004  # the cycle's 2 mN noise
    on, off = contact_thresholds(rec)
    assert (on, off) == (run["features"]["contact_on_n"], run["features"]["contact_off_n"])
    assert 3 * run["contact"]["force_noise_floor_n"] <= off < 0.1  # not the bench's 0.25 N
    assert run["contact"]["cycles"] == 1


def test_compression_recorded_negative_imports_as_compression(tmp_path, rt_loop, capsys):
    """A machine that records compression as negative displacement and force: imported as it
    is, the series is tension and no cycle is segmented, and the summary names the option;
    with `compression_negative` it is the same recording as the positive one, every feature
    and the segmented cycle included, and the metadata says the signs were negated."""
    c = cycle()
    pos = {"t [s]": c["time"], "x [mm]": c["displacement"], "f [N]": c["force"]}
    neg = {"t [s]": c["time"], "x [mm]": -c["displacement"], "f [N]": -c["force"]}
    want = _import(tmp_path, rt_loop, pos)
    as_is = _import(tmp_path, rt_loop, neg)
    assert as_is.meta["haptics.run"]["contact"]["cycles"] == 0
    assert "needs --compression-negative" in describe_import(as_is)
    got = _import(tmp_path, rt_loop, neg, compression_negative=True)
    run = got.meta["haptics.run"]
    assert run["contact"]["loading"] == "compression" and run["contact"]["cycles"] == 1
    assert run["preprocessing"]["compression_negative"] is True
    assert "signs negated (--compression-negative)" in describe_import(got)
    for col in ("position_x", "rtob_force", *NINE):
        np.testing.assert_allclose(got.column(col), want.column(col), rtol=0, atol=1e-12,
                                   err_msg=col)  # fmt: skip


def test_given_gains_and_thresholds_are_used(tmp_path, rt_loop):
    c = cycle()
    rec = _import(tmp_path, rt_loop, {"t": c["time"], "x [mm]": c["displacement"],
                                      "f": c["force"]}, g_v=5.0, g_a=20.0,
                  contact_on_n=0.3, contact_off_n=0.2)  # fmt: skip
    run = rec.meta["haptics.run"]
    assert (run["filters"]["g_v"], run["filters"]["g_a"]) == (5.0, 20.0)
    assert run["filters"]["g_a_from"] == "given"
    assert contact_thresholds(rec) == (0.3, 0.2)
    with pytest.raises(RuntimeError, match="contact_off_n must be below"):
        _import(tmp_path, rt_loop, {"t": c["time"], "x [mm]": c["displacement"],
                                    "f": c["force"]},
                contact_on_n=0.1, contact_off_n=0.2)  # fmt: skip


def test_derived_filters_do_not_ring_at_50_hz(tmp_path, rt_loop):
    """The issue's failure: at 50 Hz the 100 rad/s acceleration filter oscillated on 99 % of
    rows. With the derived gain the acceleration changes sign only where the motion does."""
    c = cycle()
    rec = _import(tmp_path, rt_loop, {"t": c["time"], "x [mm]": c["displacement"],
                                      "f": c["force"]})  # fmt: skip
    a = rec.column("acceleration")
    big = a[np.abs(a) > 0.01 * np.abs(a).max()]  # rounding-level residues on the ramps aside
    flips = int(np.sum(np.sign(big[1:]) != np.sign(big[:-1])))
    assert flips <= 3, flips  # the cycle's corners: start, top, end
    v = rec.column("velocity")
    assert v.max() == pytest.approx(2e-3, rel=0.05)  # the 2 mm/s ramp, in m/s


def test_repair_counts_and_interpolates(tmp_path, rt_loop):
    case = next(c for c in CASES if c.name == "nan_holes.csv --repair")
    status, rec = run_case(case, tmp_path, str(rt_loop))
    assert status == "ok"
    pre = rec.meta["haptics.run"]["preprocessing"]
    assert pre["repair"] is True and pre["repairs"]["interpolated_force"] == 4
    f = rec.column("rtob_force")
    assert f[101] == pytest.approx(0.5 * (f[100] + f[102]), abs=0.05 * abs(f[100]) + 1e-3)


def test_resampling_keeps_the_cycle(tmp_path, rt_loop):
    c = cycle(sample_hz=1000.0)
    rec = _import(tmp_path, rt_loop, {"t": c["time"], "x [mm]": c["displacement"],
                                      "f": c["force"]}, resample_hz=50.0)  # fmt: skip
    assert rec.sample_rate_hz == pytest.approx(50.0)
    assert len(rec) == 601
    ref = cycle(sample_hz=50.0)
    # window averages of the noisy 1 kHz force: within a few noise sd of the 50 Hz truth
    assert np.max(np.abs(rec.column("rtob_force") - ref["force"])) < 0.03
    pre = rec.meta["haptics.run"]["preprocessing"]
    assert pre["resample_hz"] == 50.0 and pre["sample_rate_in_hz"] == pytest.approx(1000.0)


def test_rt_loop_features_alone_refuses_bad_series(tmp_path, rt_loop):
    """`rt-loop features` itself (no Python in front) refuses NaN, backwards time, unstable
    gains and a unit that contradicts its header, naming the row."""
    c = cycle()

    def run(cols, *extra):
        src = tmp_path / "s.csv"
        pacsv.write_csv(pa.table(cols), src)
        names = list(cols)
        return subprocess.run(
            [str(rt_loop), "features", "--input", str(src), "--out", str(tmp_path / "o.parquet"),
             "--time-col", names[0], "--position-col", names[1], "--force-col", names[2],
             *extra], capture_output=True, text=True)  # fmt: skip

    f = c["force"].copy()
    f[10] = np.nan
    p = run({"t": c["time"], "x": c["displacement"], "f": f})
    assert p.returncode != 0 and "row 11: force is missing" in p.stderr
    p = run({"t": c["time"], "x": c["displacement"], "f [mN]": c["force"]}, "--force-unit", "N")
    assert p.returncode != 0 and "says its unit is mN" in p.stderr
    p = run({"t": c["time"], "x": c["displacement"], "f": c["force"]}, "--g-a", "100")
    assert p.returncode != 0 and "g dt = 2.000" in p.stderr
    p = run({"t": c["time"], "x [mm]": c["displacement"], "f [mN]": c["force"]})
    assert p.returncode == 0, p.stderr
    assert "50.000 Hz" in p.stderr


def test_loader_refuses_non_finite_rows(tmp_path):
    from haptics_train.data import load_recording

    p = write_recording(tmp_path / "r.parquet", ramp_rate=6.2, cycles=1)
    t = pq.read_table(p)
    f = t.column("rtob_force").to_numpy().copy()
    f[17] = np.nan
    bad = tmp_path / "bad.parquet"
    pq.write_table(t.set_column(t.schema.get_field_index("rtob_force"), "rtob_force",
                                pa.array(f)), bad)  # fmt: skip
    with pytest.raises(DataError, match="row 18: column 'rtob_force' is nan"):
        load_recording(bad)


def test_cli_import_honours_force_unit_and_writes_a_manifest(tmp_path, rt_loop, capsys):
    """The issue's bug: `--force-unit mN` was silently ignored by the command."""
    from haptics_train.cli import main
    from haptics_train.data import load_manifest

    c = cycle()
    src = tmp_path / "in.csv"
    pacsv.write_csv(pa.table({"t": c["time"], "x": c["displacement"],
                              "F": 1e3 * c["force"]}), src)  # fmt: skip
    man = tmp_path / "dataset.toml"
    for role in ("train", "validation", "test"):
        main(["import", "--input", str(src), "--out", str(tmp_path / f"{role}.parquet"),
              "--time-col", "t", "--position-col", "x", "--force-col", "F",
              "--position-unit", "mm", "--force-unit", "mN", "--rt-loop", str(rt_loop),
              "--manifest", str(man), "--role", role, "--source", "fixture",
              "--notes", f"the {role} copy"])  # fmt: skip
    assert "force mN (option)" in capsys.readouterr().out
    ds = load_manifest(man)
    assert [r.name for r in ds.train] == ["train"] and [r.name for r in ds.test] == ["test"]
    assert ds.validation[0].notes == "the validation copy" and ds.train[0].origin == "fixture"
    np.testing.assert_allclose(ds.train[0].column("rtob_force"), c["force"], rtol=1e-12)


def test_bare_csv_in_mn_and_mm_is_refused_naming_the_option(tmp_path, rt_loop):
    """A plain `time,displacement,force` file in mN and mm is never taken as N and m silently:
    the force reaches 14 000 'N', over the 1 kN a bench gives, and the error names the option."""
    c = cycle()
    cols = {"time": c["time"], "displacement": c["displacement"], "force": 1e3 * c["force"]}
    with pytest.raises(DataError, match="names no unit.*--force-unit"):
        _import(tmp_path, rt_loop, cols)
    cols = {"time": c["time"], "displacement": 1e3 * c["displacement"], "force": c["force"]}
    with pytest.raises(DataError, match="over 1 m.*--position-unit"):
        _import(tmp_path, rt_loop, cols)
    assert not (tmp_path / "out.parquet").exists()


def test_cli_says_which_units_were_assumed_and_refuses_to_overwrite(tmp_path, rt_loop, capsys):
    from haptics_train.cli import main

    c = cycle()
    src = tmp_path / "in.csv"
    pacsv.write_csv(pa.table({"time": c["time"], "displacement": c["displacement"],
                              "force": c["force"]}), src)  # fmt: skip
    out = tmp_path / "o.parquet"
    args = ["import", "--input", str(src), "--out", str(out), "--time-col", "time",
            "--position-col", "displacement", "--force-col", "force", "--position-unit", "mm",
            "--rt-loop", str(rt_loop)]  # fmt: skip
    main(args)
    err = capsys.readouterr().err
    assert "no unit for time (column 'time') in its header or --time-unit: taken as s" in err
    assert "no unit for force" in err and "position" not in err
    before = out.stat().st_mtime_ns
    with pytest.raises(SystemExit):
        main(args)
    assert "exists: give --overwrite to replace it" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == before
    main([*args, "--overwrite"])


def test_cli_errors_are_one_line_and_debug_shows_the_traceback(tmp_path, capsys):
    from haptics_train.cli import main

    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x0f\xff this is not protobuf \x00\x01" * 7)
    with pytest.raises(SystemExit) as e:
        main(["validate", str(garbage)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith("haptics-train validate: error: ") and "not an ONNX model" in err
    with pytest.raises(Exception, match="not an ONNX model"):
        main(["--debug", "validate", str(garbage)])


# --- testing machines' text exports (haptics_train.csv_layout) ---


def _cycle_cells():
    """One cycle as text cells with fixed digits, so every layout below holds the same numbers."""
    c = cycle()
    return [(f"{t:.3f}", f"{x:.5f}", f"{f:.5f}")
            for t, x, f in zip(c["time"], c["displacement"], c["force"], strict=True)]  # fmt: skip


def _write_plain(path, cells):
    path.write_text("t [s],x [mm],f [N]\n" + "".join(f"{a},{b},{c}\n" for a, b, c in cells))
    return path


EXPORTS = {
    # a German-language export: preamble, ';', decimal commas, CRLF, Windows-1252
    "semicolon_decimal_comma.csv": lambda cells: (
        "Prüfprotokoll;Probe A\r\nDatum;20.11.2026\r\n\r\nt [s];x [mm];f [N]\r\n"
        + "".join(f"{a};{b};{c}\r\n".replace(".", ",") for a, b, c in cells)
    ).encode("cp1252"),
    # quoted cells and a units row under the header, a byte-order mark
    "units_row.csv": lambda cells: (
        '\ufeff"t","x","f"\n"(s)","(mm)","(N)"\n'
        + "".join(f'"{a}","{b}","{c}"\n' for a, b, c in cells)
    ).encode("utf-8"),
    # tabs, units in brackets in a row of their own, a trailing tab on every line
    "tabs.txt": lambda cells: (
        "t\tx\tf\t\n[s]\t[mm]\t[N]\t\n" + "".join(f"{a}\t{b}\t{c}\t\n" for a, b, c in cells)
    ).encode("utf-8"),
}


@pytest.mark.parametrize("name", list(EXPORTS))
def test_a_text_export_imports_as_the_plain_file(name, tmp_path, rt_loop):
    """The same numbers laid out as a testing machine's software writes them give the same
    recording as the plain comma-separated file, every feature included, and the metadata says
    how the file was read."""
    cells = _cycle_cells()
    want = import_series(_write_plain(tmp_path / "plain.csv", cells), tmp_path / "a.parquet",
                         "t", "x", "f", rt_loop=str(rt_loop))  # fmt: skip
    src = tmp_path / name
    src.write_bytes(EXPORTS[name](cells))
    got = import_series(src, tmp_path / "b.parquet", "t", "x", "f", rt_loop=str(rt_loop))
    assert len(got) == len(want) == len(cells)
    for col in ("time", "position_x", "rtob_force", *NINE):
        np.testing.assert_array_equal(got.column(col), want.column(col), err_msg=col)
    layout = got.meta["haptics.run"]["preprocessing"]["text_layout"]
    assert want.meta["haptics.run"]["preprocessing"]["text_layout"] == {
        "separator": ",", "decimal_comma": False, "header_line": 1, "units_row": False,
        "encoding": "utf-8"}  # fmt: skip
    expected = {
        "semicolon_decimal_comma.csv": {"separator": ";", "decimal_comma": True,
                                        "header_line": 4, "units_row": False,
                                        "encoding": "cp1252"},
        "units_row.csv": {"separator": ",", "decimal_comma": False, "header_line": 1,
                          "units_row": True, "encoding": "utf-8"},
        "tabs.txt": {"separator": "\t", "decimal_comma": False, "header_line": 1,
                     "units_row": True, "encoding": "utf-8"},
    }[name]  # fmt: skip
    assert layout == expected
    units = got.meta["haptics.run"]["units"]
    assert {k: (v["unit"], v["from"]) for k, v in units.items()} == {
        "time": ("s", "header"), "position": ("mm", "header"), "force": ("N", "header")}
    assert "read as" in describe_import(got) and "read as" not in describe_import(want)


def test_a_file_naming_no_asked_column_shows_its_header(tmp_path, rt_loop):
    src = tmp_path / "export.txt"
    src.write_text("Protocol\tA\n\nTime\tExtension\tLoad\n(s)\t(mm)\t(N)\n0.0\t0.0\t0.0\n")
    with pytest.raises(DataError, match=r"line 3 \(tab-separated\): \['Time', 'Extension'"):
        import_series(src, tmp_path / "o.parquet", "Zeit", "Weg", "Kraft", rt_loop=str(rt_loop))


def test_a_repeated_column_name_is_refused(tmp_path, rt_loop):
    src = tmp_path / "twice.csv"
    src.write_text("t [s],x [mm],f,f\n0,0,0,0\n0.02,0.1,0.1,0.2\n0.04,0.2,0.2,0.4\n")
    with pytest.raises(DataError, match="'f' is ambiguous"):
        import_series(src, tmp_path / "o.parquet", "t", "x", "f", rt_loop=str(rt_loop))


def test_a_file_without_a_time_column_imports_at_its_sampling_rate(tmp_path, rt_loop):
    """A DAQ's samples with no time column, given their rate, make the recording the same
    samples with a time column make; neither or both of the two is refused."""
    cells = _cycle_cells()  # 50 Hz: time 0.000, 0.020, ...
    want = import_series(_write_plain(tmp_path / "plain.csv", cells), tmp_path / "a.parquet",
                         "t", "x", "f", rt_loop=str(rt_loop))  # fmt: skip
    src = tmp_path / "daq.csv"
    src.write_text("f [N];x [mm]\n" + "".join(f"{c};{b}\n".replace(".", ",")
                                             for _, b, c in cells))  # fmt: skip
    got = import_series(src, tmp_path / "b.parquet", None, "x", "f", sample_rate_hz=50.0,
                        rt_loop=str(rt_loop))  # fmt: skip
    for col in ("time", "position_x", "rtob_force", *NINE):
        np.testing.assert_allclose(got.column(col), want.column(col), rtol=0, atol=1e-9,
                                   err_msg=col)  # fmt: skip
    pre = got.meta["haptics.run"]["preprocessing"]
    assert pre["sample_rate_given_hz"] == 50.0
    assert pre["units"]["time"] == {"unit": "s", "from": "sample rate", "column": None}
    assert "a lost sample cannot be seen" in describe_import(got)
    for kw in ({}, {"sample_rate_hz": 50.0, "time_col": "f"}):
        time_col = kw.pop("time_col", None)
        with pytest.raises(DataError, match="one of the two"):
            import_series(src, tmp_path / "c.parquet", time_col, "x", "f", rt_loop=str(rt_loop),
                          **kw)  # fmt: skip
    with pytest.raises(DataError, match="--time-unit is the unit of a time column"):
        import_series(src, tmp_path / "c.parquet", None, "x", "f", sample_rate_hz=50.0,
                      time_unit="ms", rt_loop=str(rt_loop))  # fmt: skip
