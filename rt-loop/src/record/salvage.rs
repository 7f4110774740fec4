//! A failed recording (a full disk, an I/O error) keeps what reached the file readable: the
//! recorder closes the `.partial` over the rows written before the error, so it is a valid file
//! of those rows, and says how many (docs/recording-format.md, "A failed recording").
//!
//! - Parquet: the row groups the writer completed are in the file, but a Parquet file without
//!   its footer is unreadable. The file is cut right after the last complete row group (which
//!   also frees the space the failed one took) and the footer over those row groups is written
//!   (`ParquetMetaDataWriter`), with the run's `haptics.run` metadata. No complete row group: the
//!   file becomes a valid Parquet file of no rows.
//! - CSV: cut after the last complete line.
//! - MCAP: left as written: the chunks completed before the error are whole records, which an
//!   MCAP reader in streaming mode reads (the summary and footer are missing, so an indexed
//!   reader refuses it); the rows are those of the completed chunks.
use std::fs::OpenOptions;
use std::io::{Read, Seek, SeekFrom, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::sync::{Arc, Mutex};

use parquet::file::metadata::{
    FileMetaData, KeyValue, ParquetMetaData, ParquetMetaDataWriter, RowGroupMetaData,
};

use super::writer::{properties, schema, Format};

/// Closes the `.partial` at `path` over what was written; returns the rows it holds.
pub fn salvage(
    path: &Path,
    format: Format,
    row_groups: &[RowGroupMetaData],
    mcap_rows: u64,
    metadata_json: &str,
) -> anyhow::Result<u64> {
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)?;
    let rows = match format {
        Format::Mcap => mcap_rows,
        Format::Csv => {
            let mut text = Vec::new();
            file.read_to_end(&mut text)?;
            let end = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            file.set_len(end as u64)?;
            // The header line is not a row.
            (text[..end].iter().filter(|&&b| b == b'\n').count() as u64).saturating_sub(1)
        }
        Format::Parquet if row_groups.is_empty() => {
            let bytes = empty_parquet(metadata_json)?;
            file.set_len(0)?;
            file.seek(SeekFrom::Start(0))?;
            file.write_all(&bytes)?;
            0
        }
        Format::Parquet => {
            let end = row_groups
                .iter()
                .flat_map(|rg| rg.columns())
                .map(|c| {
                    c.dictionary_page_offset().unwrap_or(c.data_page_offset()) + c.compressed_size()
                })
                .max()
                .unwrap_or(4);
            let rows: i64 = row_groups.iter().map(RowGroupMetaData::num_rows).sum();
            let meta = FileMetaData::new(
                1,
                rows,
                Some(format!("rt-loop {} (salvaged)", env!("CARGO_PKG_VERSION"))),
                Some(vec![KeyValue::new(
                    "haptics.run".to_string(),
                    metadata_json.to_string(),
                )]),
                row_groups[0].schema_descr_ptr(),
                None,
            );
            let meta = ParquetMetaData::new(meta, row_groups.to_vec());
            file.set_len(end as u64)?;
            file.seek(SeekFrom::Start(end as u64))?;
            ParquetMetaDataWriter::new(&mut file, &meta).finish()?;
            rows as u64
        }
    };
    file.sync_all()?;
    Ok(rows)
}

/// A valid Parquet file of the recording's columns and no rows.
fn empty_parquet(metadata_json: &str) -> anyhow::Result<Vec<u8>> {
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().map_or(Ok(0), |mut v| {
                v.extend_from_slice(b);
                Ok(b.len())
            })
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let out = Shared::default();
    let w = parquet::arrow::ArrowWriter::try_new(
        out.clone(),
        schema(),
        Some(properties(metadata_json)),
    )?;
    w.close()?;
    let bytes = out.0.lock().map(|v| v.clone()).unwrap_or_default();
    Ok(bytes)
}
