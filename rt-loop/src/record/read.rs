//! Reading recordings (and series measured elsewhere) back: named columns of a Parquet or CSV
//! file as f64, and the run metadata.

use anyhow::{anyhow, bail, Context, Result};
use arrow_array::{Array, ArrayRef};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::arrow::ProjectionMask;
use std::path::Path;

fn is_csv(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// The column names of a Parquet or CSV file (for matching `name [unit]` headers).
pub fn column_names(path: &Path) -> Result<Vec<String>> {
    if is_csv(path) {
        let mut rdr = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_path(path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        Ok(rdr.headers()?.iter().map(str::to_string).collect())
    } else {
        parquet_guard(path, || {
            let file = std::fs::File::open(path)
                .with_context(|| format!("cannot open {}", path.display()))?;
            let builder = ParquetRecordBatchReaderBuilder::try_new(file)
                .with_context(|| format!("{} is not a readable Parquet file", path.display()))?;
            Ok(builder
                .schema()
                .fields()
                .iter()
                .map(|f| f.name().clone())
                .collect())
        })
    }
}

/// Runs a Parquet read, turning a panic inside the parquet crate into an error. The crate
/// (57.x) panics on some malformed files instead of returning an error (found by fuzzing,
/// `fuzz/fuzz_targets/recording.rs`: an `unwrap` in its thrift metadata decoder); a file that
/// is not a valid recording must be refused with a message, never end the process.
fn parquet_guard<T>(path: &Path, read: impl FnOnce() -> Result<T>) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(read)).unwrap_or_else(|panic| {
        let why = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(anyhow!(
            "{} is not a readable Parquet file (the Parquet reader failed: {why})",
            path.display()
        ))
    })
}

/// The named columns, in the order asked, converted to f64 (integers and booleans exactly).
pub fn read_columns(path: &Path, names: &[&str]) -> Result<Vec<Vec<f64>>> {
    if is_csv(path) {
        read_csv(path, names)
    } else {
        parquet_guard(path, || read_parquet(path, names))
    }
}

fn to_f64(a: &ArrayRef, out: &mut Vec<f64>, name: &str) -> Result<()> {
    use arrow_array::cast::AsArray;
    use arrow_array::types::*;
    macro_rules! prim {
        ($t:ty) => {{
            let p = a.as_primitive::<$t>();
            for i in 0..p.len() {
                out.push(if p.is_null(i) {
                    f64::NAN
                } else {
                    p.value(i) as f64
                });
            }
        }};
    }
    match a.data_type() {
        DataType::Float64 => prim!(Float64Type),
        DataType::Float32 => prim!(Float32Type),
        DataType::Int8 => prim!(Int8Type),
        DataType::Int16 => prim!(Int16Type),
        DataType::Int32 => prim!(Int32Type),
        DataType::Int64 => prim!(Int64Type),
        DataType::UInt8 => prim!(UInt8Type),
        DataType::UInt16 => prim!(UInt16Type),
        DataType::UInt32 => prim!(UInt32Type),
        DataType::UInt64 => prim!(UInt64Type),
        DataType::Boolean => {
            let b = a.as_boolean();
            for i in 0..b.len() {
                out.push(if b.is_null(i) {
                    f64::NAN
                } else if b.value(i) {
                    1.0
                } else {
                    0.0
                });
            }
        }
        t => bail!("column {name} has type {t}, not a number"),
    }
    Ok(())
}

fn read_parquet(path: &Path, names: &[&str]) -> Result<Vec<Vec<f64>>> {
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file)
        .with_context(|| format!("{} is not a readable Parquet file", path.display()))?;
    let schema = builder.schema().clone();
    let mut idx = Vec::with_capacity(names.len());
    for n in names {
        let i = schema.index_of(n).map_err(|_| {
            let have: Vec<_> = schema.fields().iter().map(|f| f.name().as_str()).collect();
            anyhow!(
                "{}: no column {n:?} (columns: {})",
                path.display(),
                have.join(", ")
            )
        })?;
        idx.push(i);
    }
    let mut sorted = idx.clone();
    sorted.sort_unstable();
    sorted.dedup();
    let mask = ProjectionMask::roots(builder.parquet_schema(), sorted.iter().copied());
    let reader = builder
        .with_projection(mask)
        .with_batch_size(65_536)
        .build()?;
    let mut out: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for batch in reader {
        let batch = batch?;
        for (k, n) in names.iter().enumerate() {
            let col = batch
                .column_by_name(n)
                .ok_or_else(|| anyhow!("column {n} missing in a batch"))?;
            to_f64(col, &mut out[k], n)?;
        }
    }
    Ok(out)
}

fn read_csv(path: &Path, names: &[&str]) -> Result<Vec<Vec<f64>>> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    let headers = rdr.headers()?.clone();
    let mut idx = Vec::with_capacity(names.len());
    for n in names {
        let i = headers.iter().position(|h| h == *n).ok_or_else(|| {
            anyhow!(
                "{}: no column {n:?} (columns: {})",
                path.display(),
                headers.iter().collect::<Vec<_>>().join(", ")
            )
        })?;
        idx.push(i);
    }
    let mut out: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for (line, rec) in rdr.records().enumerate() {
        let rec = rec?;
        for (k, &i) in idx.iter().enumerate() {
            let s = rec.get(i).unwrap_or("");
            let v = match s {
                "" => f64::NAN,
                "true" => 1.0,
                "false" => 0.0,
                _ => s.parse::<f64>().map_err(|_| {
                    anyhow!(
                        "{} line {}: column {}: {s:?} is not a number",
                        path.display(),
                        line + 2,
                        names[k]
                    )
                })?,
            };
            out[k].push(v);
        }
    }
    Ok(out)
}

/// The `haptics.run` metadata JSON (Parquet key-value metadata, or the CSV sidecar).
pub fn read_metadata(path: &Path) -> Result<Option<String>> {
    if is_csv(path) {
        let side = super::sidecar_path(path);
        return match std::fs::read_to_string(&side) {
            Ok(s) => Ok(Some(s)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(e.into()),
        };
    }
    parquet_guard(path, || {
        let file = std::fs::File::open(path)?;
        let builder = ParquetRecordBatchReaderBuilder::try_new(file)?;
        let kv = builder.metadata().file_metadata().key_value_metadata();
        Ok(kv.and_then(|kv| {
            kv.iter()
                .find(|k| k.key == "haptics.run")
                .and_then(|k| k.value.clone())
        }))
    })
}
