//! MCAP recordings (`rt-loop run --format mcap`, or a `.mcap` path): the robotics log format
//! Foxglove and PlotJuggler open, written with the maintained `mcap` crate. Messages are JSON
//! with a JSON Schema per channel (docs/recording-format.md, "MCAP"):
//!
//! | topic | schema | one message per |
//! | --- | --- | --- |
//! | `/haptics/row` | `haptics.Row` | recorded step: every column of the Parquet recording |
//! | `/haptics/features` | `haptics.Features` | recorded step: `step`, `time` and the nine features |
//! | `/haptics/phase` | `haptics.PhaseEvent` | change of phase or cycle: step, time, phase, its name, cycle |
//! | `/haptics/run` | `haptics.Run` | run: the run metadata (`haptics.run`), once at time 0 |
//!
//! The run metadata is also the file's MCAP Metadata record `haptics` (key `haptics.run`).
//! A message's log time is the step's `time` in nanoseconds. Floats are written as their
//! shortest round-trip text (serde_json), so reading back gives identical values; NaN (F_true and
//! F_object on a real board, F_pred without a model) is `null`. Each property of a schema names its Arrow
//! type (`x-arrow-type`), so a converter can restore the Parquet columns exactly
//! (`haptics-mcap`, client/src/haptics/mcap_format.py).

use super::row::Row;
use super::writer::{batch, schema, CountingWriter};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float64Type, Int32Type, UInt16Type, UInt32Type, UInt64Type, UInt8Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use haptics_proto::features::THESIS_FEATURES;
use haptics_proto::phase::PHASE_NAMES;
use mcap::records::{MessageHeader, Metadata};
use mcap::write::{NoSeek, WriteOptions, Writer};
use std::collections::BTreeMap;
use std::fmt::Write as _;

pub const ROW_TOPIC: &str = "/haptics/row";
pub const FEATURES_TOPIC: &str = "/haptics/features";
pub const PHASE_TOPIC: &str = "/haptics/phase";
pub const RUN_TOPIC: &str = "/haptics/run";

/// Rows are buffered this many at a time, turned into one Arrow batch (the Parquet writer's
/// own column mapping) and written as messages.
const BATCH: usize = 8192;

pub struct McapSink {
    writer: Writer<NoSeek<CountingWriter>>,
    row_channel: u16,
    features_channel: u16,
    phase_channel: u16,
    buf: Vec<Row>,
    /// Columns of `/haptics/features`: indices into the recording's schema.
    feature_columns: Vec<usize>,
    /// The last (phase, cycle) an event was written for.
    last_phase: Option<(u8, u32)>,
    phase_seq: u32,
    rows_written: u64,
    text: Vec<String>,
}

/// `{"type": "object", "properties": {...}}` for these columns of the recording's schema.
fn json_schema(title: &str, description: &str, columns: &[usize]) -> String {
    let schema = schema();
    let mut props = serde_json::Map::new();
    for &i in columns {
        let f = schema.field(i);
        let (ty, arrow) = json_type(f.data_type());
        props.insert(
            f.name().clone(),
            serde_json::json!({ "type": ty, "x-arrow-type": arrow }),
        );
    }
    serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": props,
        "required": columns.iter().map(|&i| schema.field(i).name().clone()).collect::<Vec<_>>(),
    })
    .to_string()
}

/// The JSON Schema type and the Arrow type name (as pyarrow spells it) of a column.
fn json_type(t: &DataType) -> (serde_json::Value, &'static str) {
    use serde_json::json;
    match t {
        DataType::UInt64 => (json!("integer"), "uint64"),
        DataType::UInt32 => (json!("integer"), "uint32"),
        DataType::Int32 => (json!("integer"), "int32"),
        DataType::UInt16 => (json!("integer"), "uint16"),
        DataType::UInt8 => (json!("integer"), "uint8"),
        DataType::Boolean => (json!("boolean"), "bool"),
        // NaN has no JSON spelling: null
        _ => (json!(["number", "null"]), "double"),
    }
}

/// Appends `"name":value` of row `i` of every listed column to `out[i]`.
fn append_columns(b: &RecordBatch, columns: &[usize], out: &mut [String]) {
    for &c in columns {
        let name = b.schema_ref().field(c).name().clone();
        let a = b.column(c);
        for (i, s) in out.iter_mut().enumerate() {
            if s.len() > 1 {
                s.push(',');
            }
            let _ = write!(s, "\"{name}\":");
            match a.data_type() {
                DataType::UInt64 => push_int(s, a.as_primitive::<UInt64Type>().value(i)),
                DataType::UInt32 => push_int(s, a.as_primitive::<UInt32Type>().value(i)),
                DataType::Int32 => push_int(s, a.as_primitive::<Int32Type>().value(i)),
                DataType::UInt16 => push_int(s, a.as_primitive::<UInt16Type>().value(i)),
                DataType::UInt8 => push_int(s, a.as_primitive::<UInt8Type>().value(i)),
                DataType::Boolean => s.push_str(if a.as_boolean().value(i) {
                    "true"
                } else {
                    "false"
                }),
                _ => push_f64(s, a.as_primitive::<Float64Type>().value(i)),
            }
        }
    }
}

fn push_int(s: &mut String, v: impl std::fmt::Display) {
    let _ = write!(s, "{v}");
}

fn push_f64(s: &mut String, v: f64) {
    if v.is_finite() {
        // serde_json's float text is the shortest that parses back to the same f64
        s.push_str(&serde_json::Number::from_f64(v).expect("finite").to_string());
    } else {
        // NaN (and the infinities, which no column holds) have no JSON spelling
        s.push_str("null");
    }
}

fn nanos(time_s: f64) -> u64 {
    (time_s.max(0.0) * 1e9).round() as u64
}

impl McapSink {
    pub fn new(w: CountingWriter, metadata_json: &str) -> anyhow::Result<McapSink> {
        let mut writer = WriteOptions::new()
            .disable_seeking(true)
            .profile("")
            .library(format!("rt-loop {}", env!("CARGO_PKG_VERSION")))
            .create(NoSeek::new(w))?;
        let schema = schema();
        let all: Vec<usize> = (0..schema.fields().len()).collect();
        let index = |name: &str| schema.index_of(name).expect("a recorded column");
        let mut feature_columns = vec![index("step"), index("time")];
        feature_columns.extend(THESIS_FEATURES.iter().map(|f| index(f)));
        let none = BTreeMap::new();
        let mut channel = |topic: &str, name: &str, text: String| -> anyhow::Result<u16> {
            let id = writer.add_schema(name, "jsonschema", text.as_bytes())?;
            Ok(writer.add_channel(id, topic, "json", &none)?)
        };
        let row_channel = channel(
            ROW_TOPIC,
            "haptics.Row",
            json_schema(
                "haptics.Row",
                "One recorded control step: the columns of docs/recording-format.md",
                &all,
            ),
        )?;
        let features_channel = channel(
            FEATURES_TOPIC,
            "haptics.Features",
            json_schema(
                "haptics.Features",
                "The nine features of thesis Table 3.1 at one recorded step",
                &feature_columns,
            ),
        )?;
        let phase_channel = channel(
            PHASE_TOPIC,
            "haptics.PhaseEvent",
            serde_json::json!({
                "$schema": "https://json-schema.org/draft/2020-12/schema",
                "title": "haptics.PhaseEvent",
                "description": "The experiment entered a phase (or a new cycle) at this step",
                "type": "object",
                "properties": {
                    "step": { "type": "integer" },
                    "time": { "type": "number" },
                    "phase": { "type": "integer" },
                    "name": { "type": "string", "enum": PHASE_NAMES },
                    "cycle_no": { "type": "integer" },
                },
                "required": ["step", "time", "phase", "name", "cycle_no"],
            })
            .to_string(),
        )?;
        let run_channel = channel(
            RUN_TOPIC,
            "haptics.Run",
            serde_json::json!({
                "$schema": "https://json-schema.org/draft/2020-12/schema",
                "title": "haptics.Run",
                "description": "The run's metadata (haptics.run): experiment, board, material, seed, clock, loop parameters",
                "type": "object",
                "properties": { "run": { "type": "object" } },
                "required": ["run"],
            })
            .to_string(),
        )?;
        let run: serde_json::Value =
            serde_json::from_str(metadata_json).unwrap_or(serde_json::Value::Null);
        let data = serde_json::json!({ "run": run }).to_string();
        writer.write_to_known_channel(
            &MessageHeader {
                channel_id: run_channel,
                sequence: 0,
                log_time: 0,
                publish_time: 0,
            },
            data.as_bytes(),
        )?;
        writer.write_metadata(&Metadata {
            name: "haptics".into(),
            metadata: BTreeMap::from([("haptics.run".to_string(), metadata_json.to_string())]),
        })?;
        Ok(McapSink {
            writer,
            row_channel,
            features_channel,
            phase_channel,
            buf: Vec::with_capacity(BATCH),
            feature_columns,
            last_phase: None,
            phase_seq: 0,
            rows_written: 0,
            text: Vec::with_capacity(BATCH),
        })
    }

    pub fn push(&mut self, rows: &[Row]) -> anyhow::Result<()> {
        for r in rows {
            self.buf.push(*r);
            if self.buf.len() == BATCH {
                self.write_buffered()?;
            }
        }
        Ok(())
    }

    fn write_buffered(&mut self) -> anyhow::Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let b = batch(&self.buf)?;
        let all: Vec<usize> = (0..b.num_columns()).collect();
        let fc = self.feature_columns.clone();
        let row_channel = self.row_channel;
        let features_channel = self.features_channel;
        for (channel, columns) in [(row_channel, &all), (features_channel, &fc)] {
            self.text.clear();
            self.text.resize(self.buf.len(), String::new());
            for s in self.text.iter_mut() {
                s.clear();
                s.push('{');
            }
            append_columns(&b, columns, &mut self.text);
            for (r, s) in self.buf.iter().zip(self.text.iter_mut()) {
                s.push('}');
                let t = nanos(r.time);
                self.writer.write_to_known_channel(
                    &MessageHeader {
                        channel_id: channel,
                        sequence: r.step as u32,
                        log_time: t,
                        publish_time: t,
                    },
                    s.as_bytes(),
                )?;
            }
        }
        for r in &self.buf {
            if self.last_phase != Some((r.phase, r.cycle_no)) {
                self.last_phase = Some((r.phase, r.cycle_no));
                let name = PHASE_NAMES
                    .get(r.phase as usize)
                    .copied()
                    .unwrap_or("unknown");
                let mut s = String::with_capacity(96);
                let _ = write!(s, "{{\"step\":{},\"time\":", r.step);
                push_f64(&mut s, r.time);
                let _ = write!(
                    s,
                    ",\"phase\":{},\"name\":\"{name}\",\"cycle_no\":{}}}",
                    r.phase, r.cycle_no
                );
                let t = nanos(r.time);
                self.writer.write_to_known_channel(
                    &MessageHeader {
                        channel_id: self.phase_channel,
                        sequence: self.phase_seq,
                        log_time: t,
                        publish_time: t,
                    },
                    s.as_bytes(),
                )?;
                self.phase_seq += 1;
            }
        }
        self.rows_written += self.buf.len() as u64;
        self.buf.clear();
        Ok(())
    }

    /// Rows readable in the partial file if the run failed now: none (an MCAP file without
    /// its footer is readable only by a recovering reader; counted as lost, like Parquet).
    pub fn rows_flushed(&self) -> u64 {
        0
    }

    /// Writes what is buffered and the summary, returns the bytes written.
    pub fn finish(mut self) -> anyhow::Result<u64> {
        self.write_buffered()?;
        self.writer.finish()?;
        let mut w = self.writer.into_inner().into_inner();
        std::io::Write::flush(&mut w)?;
        Ok(w.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::{Format, Sink};
    use std::sync::{Arc, Mutex};

    /// A writer whose bytes the test reads back after the sink is gone.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn every_row_reads_back_exactly_with_the_mcap_crates_reader() {
        let out = Shared::default();
        let meta = r#"{"experiment":"abstraction","seed":7}"#;
        let mut sink = Sink::new(Format::Mcap, Box::new(out.clone()), meta).unwrap();
        // more rows than one batch, NaN predictions on every other row, four phases
        let n = BATCH as u64 * 2 + 123;
        let rows: Vec<Row> = (0..n)
            .map(|i| Row {
                step: i,
                time: i as f64 * 1e-4,
                rtob_force: i as f64 / 3.0,
                f_pred: if i % 2 == 0 { f64::NAN } else { 0.1 * i as f64 },
                phase: (i * 4 / n) as u8,
                cycle_no: 1,
                counts: -(i as i32),
                fallback: i % 3 == 0,
                ..Row::default()
            })
            .collect();
        sink.push(&rows).unwrap();
        sink.finish().unwrap();
        let bytes = out.0.lock().unwrap().clone();
        let mut counts = BTreeMap::new();
        let mut row_i = 0usize;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            *counts.entry(m.channel.topic.clone()).or_insert(0u64) += 1;
            let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
            match m.channel.topic.as_str() {
                ROW_TOPIC => {
                    let r = &rows[row_i];
                    assert_eq!(v["step"].as_u64(), Some(r.step));
                    assert_eq!(v["rtob_force"].as_f64(), Some(r.rtob_force), "bit-exact");
                    assert_eq!(
                        v["F_pred"].as_f64(),
                        (!r.f_pred.is_nan()).then_some(r.f_pred)
                    );
                    assert_eq!(v["counts"].as_i64(), Some(i64::from(r.counts)));
                    assert_eq!(v["fallback"].as_bool(), Some(r.fallback));
                    assert_eq!(m.log_time, nanos(r.time));
                    row_i += 1;
                }
                PHASE_TOPIC => assert_eq!(
                    v["name"],
                    PHASE_NAMES[v["phase"].as_u64().unwrap() as usize]
                ),
                RUN_TOPIC => assert_eq!(v["run"]["seed"], 7),
                _ => assert_eq!(v.as_object().unwrap().len(), 2 + THESIS_FEATURES.len()),
            }
        }
        assert_eq!(counts[ROW_TOPIC], n);
        assert_eq!(counts[FEATURES_TOPIC], n);
        assert_eq!(counts[PHASE_TOPIC], 4);
        assert_eq!(counts[RUN_TOPIC], 1);
    }
}
