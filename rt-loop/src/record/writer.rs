//! The file formats: Parquet through arrow-rs (zstd, byte-stream-split floats, delta-encoded
//! integers) and CSV (shortest round-trip float text, so reading back gives identical values).

use super::row::{Row, COLUMNS};
use arrow_array::types::{Float64Type, Int32Type, UInt16Type, UInt32Type, UInt64Type, UInt8Type};
use arrow_array::{ArrayRef, ArrowPrimitiveType, BooleanArray, PrimitiveArray, RecordBatch};
use arrow_schema::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, Encoding, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;
use std::io::Write;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    Parquet,
    Csv,
    /// MCAP with JSON messages (record/mcap_format.rs)
    Mcap,
}

impl Format {
    pub fn from_path(path: &std::path::Path) -> Format {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("csv") => Format::Csv,
            Some(e) if e.eq_ignore_ascii_case("mcap") => Format::Mcap,
            _ => Format::Parquet,
        }
    }
}

pub fn schema() -> Arc<Schema> {
    let t = |name: &str| -> DataType {
        match name {
            "step" => DataType::UInt64,
            "timestamp" | "cycle_no" => DataType::UInt32,
            "counts" => DataType::Int32,
            "analog_out_motor" => DataType::UInt16,
            "phase" => DataType::UInt8,
            "fallback" => DataType::Boolean,
            _ => DataType::Float64,
        }
    };
    Arc::new(Schema::new(
        COLUMNS
            .iter()
            .map(|c| Field::new(*c, t(c), false))
            .collect::<Vec<_>>(),
    ))
}

/// Rows are buffered this many at a time before they become an Arrow batch.
const BATCH: usize = 65_536;

#[allow(clippy::large_enum_variant)] // one per recording, never moved in a hot path
pub enum Sink {
    Parquet {
        writer: ArrowWriter<CountingWriter>,
        buf: Vec<Row>,
        rows_in_writer: u64,
    },
    Csv {
        out: std::io::BufWriter<CountingWriter>,
        rows_flushed: u64,
        rows_pending: u64,
        line: String,
    },
    Mcap(super::mcap_format::McapSink),
}

/// Counts bytes written (for the summary) around any writer.
pub struct CountingWriter {
    inner: Box<dyn Write + Send>,
    pub(super) bytes: u64,
}

impl Write for CountingWriter {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(b)?;
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// One column of `rows`, `f` picking each row's value (every numeric column is built here).
fn col<T: ArrowPrimitiveType>(rows: &[Row], f: impl Fn(&Row) -> T::Native) -> ArrayRef {
    Arc::new(PrimitiveArray::<T>::from_iter_values(rows.iter().map(f)))
}

fn f64_col(rows: &[Row], f: impl Fn(&Row) -> f64) -> ArrayRef {
    col::<Float64Type>(rows, f)
}

pub(super) fn batch(rows: &[Row]) -> Result<RecordBatch, arrow_schema::ArrowError> {
    let cols: Vec<ArrayRef> = vec![
        col::<UInt64Type>(rows, |r| r.step),
        col::<UInt32Type>(rows, |r| r.timestamp),
        f64_col(rows, |r| r.time),
        f64_col(rows, |r| r.dt),
        f64_col(rows, |r| r.f_ref),
        f64_col(rows, |r| r.rtob_force),
        f64_col(rows, |r| r.dob_force),
        col::<Int32Type>(rows, |r| r.counts),
        f64_col(rows, |r| r.position_x),
        f64_col(rows, |r| r.velocity),
        f64_col(rows, |r| r.acceleration),
        f64_col(rows, |r| r.i_a_ref),
        f64_col(rows, |r| r.i_motor),
        col::<UInt16Type>(rows, |r| r.analog_out_motor),
        col::<UInt8Type>(rows, |r| r.phase),
        f64_col(rows, |r| r.f_true),
        f64_col(rows, |r| r.f_pred),
        Arc::new(BooleanArray::from_iter(
            rows.iter().map(|r| Some(r.fallback)),
        )),
        col::<UInt32Type>(rows, |r| r.cycle_no),
        f64_col(rows, |r| r.f_previous_x),
        f64_col(rows, |r| r.f_previous_v),
        f64_col(rows, |r| r.f_previous_a),
        f64_col(rows, |r| r.deformation),
        f64_col(rows, |r| r.area_fx),
        f64_col(rows, |r| r.f_object),
    ];
    RecordBatch::try_new(schema(), cols)
}

pub(super) fn properties(metadata_json: &str) -> WriterProperties {
    let mut b = WriterProperties::builder()
        .set_compression(Compression::ZSTD(
            ZstdLevel::try_new(3).expect("valid level"),
        ))
        // 128 Ki rows per row group: memory stays bounded and a full disk shows up early
        .set_max_row_group_size(1 << 17)
        .set_key_value_metadata(Some(vec![KeyValue::new(
            "haptics.run".to_string(),
            metadata_json.to_string(),
        )]));
    for c in COLUMNS {
        let path = ColumnPath::from(c);
        b = match c {
            // slowly varying integers: delta encoding makes them nearly free
            "step" | "timestamp" | "counts" => b
                .set_column_dictionary_enabled(path.clone(), false)
                .set_column_encoding(path, Encoding::DELTA_BINARY_PACKED),
            // few distinct values: dictionary + RLE
            "phase" | "cycle_no" | "fallback" | "analog_out_motor" | "deformation" | "area_fx"
            | "F_pred" => b,
            // noisy floats: byte-stream-split lets zstd find the repeated exponent bytes
            _ => b
                .set_column_dictionary_enabled(path.clone(), false)
                .set_column_encoding(path, Encoding::BYTE_STREAM_SPLIT),
        };
    }
    b.build()
}

impl Sink {
    pub fn new(
        format: Format,
        w: Box<dyn Write + Send>,
        metadata_json: &str,
    ) -> anyhow::Result<Sink> {
        let cw = CountingWriter { inner: w, bytes: 0 };
        Ok(match format {
            Format::Parquet => Sink::Parquet {
                writer: ArrowWriter::try_new(cw, schema(), Some(properties(metadata_json)))?,
                buf: Vec::with_capacity(BATCH),
                rows_in_writer: 0,
            },
            Format::Csv => {
                let mut out = std::io::BufWriter::with_capacity(1 << 20, cw);
                writeln!(out, "{}", COLUMNS.join(","))?;
                Sink::Csv {
                    out,
                    rows_flushed: 0,
                    rows_pending: 0,
                    line: String::with_capacity(512),
                }
            }
            Format::Mcap => Sink::Mcap(super::mcap_format::McapSink::new(cw, metadata_json)?),
        })
    }

    pub fn push(&mut self, rows: &[Row]) -> anyhow::Result<()> {
        match self {
            Sink::Parquet {
                writer,
                buf,
                rows_in_writer,
            } => {
                for r in rows {
                    buf.push(*r);
                    if buf.len() == BATCH {
                        writer.write(&batch(buf)?)?;
                        *rows_in_writer += buf.len() as u64;
                        buf.clear();
                    }
                }
                Ok(())
            }
            Sink::Csv {
                out,
                rows_flushed,
                rows_pending,
                line,
            } => {
                use std::fmt::Write as _;
                for r in rows {
                    line.clear();
                    // `{:?}` on f64 is the shortest text that parses back to the same value
                    let _ = write!(
                        line,
                        "{},{},{:?},{:?},{:?},{:?},{:?},{},{:?},{:?},{:?},{:?},{:?},{},{},{:?},{:?},{},{},{:?},{:?},{:?},{:?},{:?},{:?}",
                        r.step, r.timestamp, r.time, r.dt, r.f_ref, r.rtob_force, r.dob_force,
                        r.counts, r.position_x, r.velocity, r.acceleration, r.i_a_ref, r.i_motor,
                        r.analog_out_motor, r.phase, r.f_true, r.f_pred, r.fallback, r.cycle_no,
                        r.f_previous_x, r.f_previous_v, r.f_previous_a, r.deformation, r.area_fx,
                        r.f_object
                    );
                    line.push('\n');
                    let before = out.get_ref().bytes;
                    out.write_all(line.as_bytes())?;
                    *rows_pending += 1;
                    if out.get_ref().bytes != before {
                        // the buffer went to the OS: everything but the rows still buffered
                        *rows_flushed += *rows_pending - 1;
                        *rows_pending = 1;
                    }
                }
                Ok(())
            }
            Sink::Mcap(m) => m.push(rows),
        }
    }

    /// Rows that would be readable in the partial file if the run failed now (Parquet: none,
    /// a Parquet file without its footer is unreadable).
    pub fn rows_flushed(&self) -> u64 {
        match self {
            Sink::Parquet { .. } => 0,
            Sink::Csv { rows_flushed, .. } => *rows_flushed,
            Sink::Mcap(m) => m.rows_flushed(),
        }
    }

    /// The Parquet row groups already complete in the file (none for CSV): what a failed
    /// recording can still be closed over (`super::salvage`).
    pub fn flushed_row_groups(&self) -> Vec<parquet::file::metadata::RowGroupMetaData> {
        match self {
            Sink::Parquet { writer, .. } => writer.flushed_row_groups().to_vec(),
            Sink::Csv { .. } | Sink::Mcap(_) => Vec::new(),
        }
    }

    /// Flushes everything, syncs, returns the bytes written.
    pub fn finish(self) -> anyhow::Result<u64> {
        match self {
            Sink::Parquet {
                mut writer, buf, ..
            } => {
                if !buf.is_empty() {
                    writer.write(&batch(&buf)?)?;
                }
                let mut cw = writer.into_inner()?;
                cw.flush()?;
                Ok(cw.bytes)
            }
            Sink::Csv { out, .. } => {
                let mut cw = out.into_inner().map_err(|e| e.into_error())?;
                cw.flush()?;
                Ok(cw.bytes)
            }
            Sink::Mcap(m) => m.finish(),
        }
    }
}
