"""MCAP recordings: rt-loop's, read with the official MCAP reader (the `mcap` Python package)
row by row against the Parquet recording of the same lockstep run, and Parquet -> MCAP ->
Parquet losing nothing."""

import json
import math
import subprocess

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import binary
from haptics_train.vocab import PHASE_NAMES, RECORDING_COLUMNS, THESIS_FEATURES
from mcap.reader import make_reader

import haptics
from haptics import mcap_format


def record(rt_loop, out, fmt):
    subprocess.run(
        [str(rt_loop), "run", "--experiment", "abstraction", "--clock", "lockstep", "--seed", "5",
         "--ramp-rate", "8", "--cycles", "2", "--record", str(out), "--format", fmt,
         "--no-progress"],
        check=True, capture_output=True, timeout=180,
    )  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    rt_loop = binary("rt-loop", "HAPTICS_RT_LOOP")
    d = tmp_path_factory.mktemp("mcap")
    record(rt_loop, d / "run.parquet", "parquet")
    record(rt_loop, d / "run.mcap", "mcap")
    return d / "run.parquet", d / "run.mcap"


def but_format(run):
    """The run metadata without `config.format` and `config.record`, the two things that two
    runs differing only by --format and --record record differently."""
    run = json.loads(json.dumps(run))
    run["config"].pop("format")
    run["config"].pop("record")
    return run


def same(a, b):
    return a == b or (isinstance(a, float) and math.isnan(a) and b is None)


def test_rt_loop_mcap_read_by_the_official_reader_has_every_row(runs):
    parquet, mcap = runs
    table = pq.read_table(parquet)
    ref = {c: table.column(c).to_pylist() for c in table.column_names}
    assert table.column_names == list(RECORDING_COLUMNS)
    n = table.num_rows
    with open(mcap, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert {t: s.name for t, s in topics.items()} == {
            "/haptics/row": "haptics.Row", "/haptics/features": "haptics.Features",
            "/haptics/phase": "haptics.PhaseEvent", "/haptics/run": "haptics.Run"}  # fmt: skip
        assert all(s.encoding == "jsonschema" for s in topics.values())
        counts = {summary.channels[k].topic: v
                  for k, v in summary.statistics.channel_message_counts.items()}  # fmt: skip
        assert counts["/haptics/row"] == counts["/haptics/features"] == n
        assert counts["/haptics/run"] == 1
        rows = features = 0
        phases = []
        for _schema, channel, msg in reader.iter_messages(log_time_order=False):
            d = json.loads(msg.data)
            if channel.topic == "/haptics/row":
                i = rows
                assert list(d) == list(RECORDING_COLUMNS)
                for c in RECORDING_COLUMNS:
                    assert same(ref[c][i], d[c]), (i, c, ref[c][i], d[c])
                assert msg.log_time == round(ref["time"][i] * 1e9)
                rows += 1
            elif channel.topic == "/haptics/features":
                i = features
                assert list(d) == ["step", "time", *THESIS_FEATURES]
                assert all(same(ref[c][i], d[c]) for c in d), i
                features += 1
            elif channel.topic == "/haptics/phase":
                phases.append(d)
            else:
                assert d["run"]["experiment"] == "abstraction" and d["run"]["seed"] == 5
        meta = {m.name: m.metadata for m in make_reader(open(mcap, "rb")).iter_metadata()}
    assert rows == features == n
    # one event per change of (phase, cycle), in order, named
    changes = [0] + [i for i in range(1, n) if (ref["phase"][i], ref["cycle_no"][i])
                     != (ref["phase"][i - 1], ref["cycle_no"][i - 1])]  # fmt: skip
    assert [p["step"] for p in phases] == [ref["step"][i] for i in changes]
    assert all(p["name"] == PHASE_NAMES[p["phase"]] for p in phases)
    run = json.loads(meta["haptics"]["haptics.run"])
    pq_run = json.loads(pq.ParquetFile(parquet).metadata.metadata[b"haptics.run"])
    assert run["config"]["format"] == "mcap" and pq_run["config"]["format"] == "parquet"
    assert but_format(run) == but_format(pq_run)
    print(f"rt-loop MCAP: {rows} rows, {features} feature messages, {len(phases)} phase events")


def test_parquet_to_mcap_to_parquet_loses_nothing(runs, tmp_path):
    parquet, rt_mcap = runs
    m = tmp_path / "conv.mcap"
    back = tmp_path / "back.parquet"
    assert mcap_format.main(["to-mcap", str(parquet), str(m)]) == 0
    assert mcap_format.main(["to-parquet", str(m), str(back)]) == 0
    a, b = pq.read_table(parquet), pq.read_table(back)
    assert a.schema.names == b.schema.names
    assert [f.type for f in a.schema] == [f.type for f in b.schema]
    assert a.num_rows == b.num_rows
    for c in a.column_names:
        x, y = a.column(c).to_numpy(), b.column(c).to_numpy()
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=c)  # NaN == NaN here, bit for bit
        else:
            assert (x == y).all(), c
    ra = pq.ParquetFile(parquet).metadata.metadata[b"haptics.run"]
    rb = pq.ParquetFile(back).schema_arrow.metadata[b"haptics.run"]
    assert json.loads(ra) == json.loads(rb)
    # the converter writes what rt-loop writes: the same rows on every channel
    def messages(path):
        with open(path, "rb") as fh:
            found = make_reader(fh).iter_messages(log_time_order=False)
            return [(c.topic, msg.log_time, json.loads(msg.data)) for _s, c, msg in found
                    if c.topic != "/haptics/run"]  # fmt: skip
    assert sorted(messages(m), key=lambda t: (t[0], t[1])) == sorted(
        messages(rt_mcap), key=lambda t: (t[0], t[1]))  # fmt: skip
    print(f"round trip: {a.num_rows} rows x {a.num_columns} columns, identical")


def test_read_recording_reads_mcap(runs):
    parquet, mcap = runs
    a, b = haptics.read_recording(parquet), haptics.read_recording(mcap)
    assert a.frame.columns == b.frame.columns
    assert a.frame.equals(b.frame, null_equal=True)
    assert but_format(a.run) == but_format(b.run)


def test_converter_refuses_to_overwrite_and_says_why(runs, tmp_path, capsys):
    parquet, _ = runs
    out = tmp_path / "x.mcap"
    out.write_text("keep me")
    assert mcap_format.main(["to-mcap", str(parquet), str(out)]) == 1
    assert "exists" in capsys.readouterr().err and out.read_text() == "keep me"
    assert mcap_format.main(["to-parquet", str(parquet), str(tmp_path / "y.parquet")]) == 1
    assert not (tmp_path / "y.parquet").exists() and not (tmp_path / "y.parquet.partial").exists()
