//! The recorder: a thread of its own, fed by the loop through a lock-free SPSC ring (`rtrb`),
//! writing Parquet (default), CSV or MCAP (mcap_format.rs) with the columns of docs/recording-format.md.
//!
//! - Files are written under `<path>.partial` and renamed to `<path>` only once complete and
//!   synced, so a crash never leaves a file that looks finished.
//! - A write failure (full disk, I/O error) never reaches the loop: the recorder keeps the
//!   first error, drains and discards the rest, and reports rows received vs written.
//! - The loop never blocks on the ring in realtime mode: a full ring drops the row and counts
//!   it ([`RecorderHandle::push_or_drop`]). In lockstep mode the loop waits for room
//!   ([`RecorderHandle::push_wait`]) so nothing is lost.

pub mod file_safety;
pub mod mcap_format;
pub mod read;
pub mod row;
mod salvage;
mod writer;

pub use row::{Row, COLUMNS};
pub use writer::{Format, Sink};

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// What the recorder did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RecorderReport {
    pub rows_received: u64,
    pub rows_written: u64,
    /// The first write error, if any (then the file was not renamed to its final name).
    pub error: Option<String>,
    /// The final file (or the partial one when it failed; None when nothing was opened).
    pub path: Option<PathBuf>,
    pub bytes: u64,
}

pub struct RecorderHandle {
    producer: rtrb::Producer<Row>,
    thread: Option<JoinHandle<RecorderReport>>,
    done: Arc<AtomicBool>,
    failed: Arc<AtomicBool>,
    dropped: u64,
    pushed: u64,
}

/// Where the recorder writes.
pub enum Target {
    /// A file path: written as `<path>.partial`, renamed on success; `<path>.meta.json`
    /// sidecar for CSV.
    File(PathBuf),
    /// Any writer (tests: /dev/full, a failing writer).
    Writer(Box<dyn std::io::Write + Send>),
}

pub fn partial_path(path: &Path) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".partial");
    PathBuf::from(s)
}

pub fn sidecar_path(path: &Path) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".meta.json");
    PathBuf::from(s)
}

impl RecorderHandle {
    /// Opens the target (errors such as a missing directory surface here, before the run) and
    /// starts the recorder thread. `metadata_json` goes into the Parquet key-value metadata as
    /// `haptics.run` (or the CSV sidecar).
    pub fn start(
        target: Target,
        format: Format,
        metadata_json: String,
        capacity: usize,
    ) -> anyhow::Result<RecorderHandle> {
        let (final_path, sink) = match target {
            Target::File(path) => {
                if path.as_os_str().is_empty() {
                    anyhow::bail!("empty record path");
                }
                // Only a regular file (or nothing) may be replaced, checked before the run.
                file_safety::check_replaceable(&path, "recording")?;
                if format == Format::Csv {
                    file_safety::check_replaceable(&sidecar_path(&path), "sidecar")?;
                }
                let tmp = partial_path(&path);
                let file = file_safety::create_new(&tmp, "recording")?;
                let sink = Sink::new(format, Box::new(file), &metadata_json)?;
                (Some(path), sink)
            }
            Target::Writer(w) => (None, Sink::new(format, w, &metadata_json)?),
        };
        let (producer, consumer) = rtrb::RingBuffer::<Row>::new(capacity.max(16));
        let done = Arc::new(AtomicBool::new(false));
        let failed = Arc::new(AtomicBool::new(false));
        let (d, f) = (done.clone(), failed.clone());
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || drain(consumer, sink, final_path, format, metadata_json, d, f))?;
        Ok(RecorderHandle {
            producer,
            thread: Some(thread),
            done,
            failed,
            dropped: 0,
            pushed: 0,
        })
    }

    /// Realtime push: never blocks; a full ring drops the row and counts it.
    #[inline]
    pub fn push_or_drop(&mut self, row: Row) -> bool {
        match self.producer.push(row) {
            Ok(()) => {
                self.pushed += 1;
                true
            }
            Err(_) => {
                self.dropped += 1;
                false
            }
        }
    }

    /// Lockstep push: waits (parking in short sleeps, never spinning) until the recorder made
    /// room, so nothing is lost. Gives up only if the recorder thread is gone.
    pub fn push_wait(&mut self, row: Row) {
        let mut row = row;
        loop {
            match self.producer.push(row) {
                Ok(()) => {
                    self.pushed += 1;
                    return;
                }
                Err(rtrb::PushError::Full(r)) => {
                    row = r;
                    if self.thread.as_ref().is_none_or(|t| t.is_finished()) {
                        self.dropped += 1;
                        return;
                    }
                    std::thread::sleep(Duration::from_micros(200));
                }
            }
        }
    }

    /// Whether a write has failed (the loop may end the run early; it stays safe either way).
    pub fn failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }

    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Ends the recording: drains the ring, closes and renames the file, joins the thread.
    pub fn finish(mut self) -> RecorderReport {
        self.done.store(true, Ordering::Release);
        let t = self.thread.take().expect("finish once");
        t.join().unwrap_or_else(|_| RecorderReport {
            error: Some("recorder thread panicked".into()),
            ..RecorderReport::default()
        })
    }
}

fn drain(
    mut consumer: rtrb::Consumer<Row>,
    mut sink: Sink,
    final_path: Option<PathBuf>,
    format: Format,
    metadata_json: String,
    done: Arc<AtomicBool>,
    failed: Arc<AtomicBool>,
) -> RecorderReport {
    let mut report = RecorderReport::default();
    let mut error: Option<String> = None;
    loop {
        let finishing = done.load(Ordering::Acquire);
        let n = consumer.slots();
        if n == 0 {
            if finishing {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let chunk = consumer.read_chunk(n).expect("slots available");
        let (a, b) = chunk.as_slices();
        report.rows_received += (a.len() + b.len()) as u64;
        if error.is_none() {
            for rows in [a, b] {
                if let Err(e) = sink.push(rows) {
                    report.rows_written = sink.rows_flushed();
                    error = Some(format!(
                        "write failed after {} of {} rows reached the file: {e}",
                        report.rows_written, report.rows_received
                    ));
                    failed.store(true, Ordering::Relaxed);
                    break;
                }
            }
            if error.is_none() {
                // rows are durable in the writer once flushed in batches; count what it took
                report.rows_written = sink.rows_flushed();
            }
        }
        chunk.commit_all();
    }
    // The row groups complete in the file: what a failed recording is closed over (salvage).
    let flushed = sink.flushed_row_groups();
    let mcap_rows = match &sink {
        Sink::Mcap(_) => sink.rows_flushed(),
        _ => 0,
    };
    if error.is_some() {
        // Closed before the salvage touches the file (a CSV buffer flushes on drop).
        drop(sink);
    } else {
        match sink.finish() {
            Ok(bytes) => {
                report.rows_written = report.rows_received;
                report.bytes = bytes;
            }
            Err(e) => {
                error = Some(format!(
                    "closing the recording failed after {} rows: {e}",
                    report.rows_written
                ));
                failed.store(true, Ordering::Relaxed);
            }
        }
    }
    if let Some(path) = final_path {
        let tmp = partial_path(&path);
        if error.is_none() {
            let renamed = (|| -> anyhow::Result<()> {
                use std::io::Write as _;
                if format == Format::Csv {
                    let side = sidecar_path(&path);
                    let side_tmp = partial_path(&side);
                    let mut f = file_safety::create_new(&side_tmp, "sidecar")?;
                    f.write_all(pretty(&metadata_json).as_bytes())?;
                    f.sync_all()?;
                    file_safety::replace(&side_tmp, &side, "sidecar")?;
                }
                std::fs::File::open(&tmp)?.sync_all()?;
                file_safety::replace(&tmp, &path, "recording")
            })();
            match renamed {
                Ok(()) => report.path = Some(path),
                Err(e) => {
                    error = Some(format!("finishing {} failed: {e}", path.display()));
                    report.path = Some(tmp);
                }
            }
        } else {
            // Keep what reached the file readable: a valid file of the rows written before the
            // error, still under its `.partial` name (it is not the whole run).
            match salvage::salvage(&tmp, format, &flushed, mcap_rows, &metadata_json) {
                Ok(rows) => {
                    report.rows_written = rows;
                    if let Some(e) = &mut error {
                        e.push_str(&format!(
                            "; the {rows} rows written before it are readable in {}",
                            tmp.display()
                        ));
                    }
                }
                Err(e2) => {
                    // Not even a footer fits: an empty file holds no row, so it is not kept.
                    let empty = std::fs::symlink_metadata(&tmp).is_ok_and(|m| m.len() == 0);
                    if empty {
                        let _ = std::fs::remove_file(&tmp);
                    }
                    if let Some(e) = &mut error {
                        e.push_str(&format!(
                            "; closing {} failed too ({e2}){}",
                            tmp.display(),
                            if empty {
                                ": no row reached the disk, the empty file was removed"
                            } else {
                                ""
                            }
                        ));
                    }
                    report.rows_written = 0;
                }
            }
            report.path = Some(tmp);
        }
    }
    if error.is_some() {
        report.rows_written = report.rows_written.min(report.rows_received);
    }
    report.error = error;
    report
}

fn pretty(json: &str) -> String {
    serde_json::from_str::<serde_json::Value>(json)
        .and_then(|v| serde_json::to_string_pretty(&v))
        .unwrap_or_else(|_| json.to_string())
}
