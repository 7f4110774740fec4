//! Recordings read back (rt-loop's record::read, used by `rt-loop features`, replay and the
//! training import): a CSV or Parquet file of any bytes gives its columns or an error, never a
//! panic. The first input byte picks the format; the rest is the file.
//!
//! The parquet crate panics on some malformed files (found here: an `unwrap` in its thrift
//! decoder, a capacity overflow from a length read from the file); rt-loop's reader contains
//! that (`parquet_guard`: the file is refused with an error). libFuzzer's panic hook aborts on
//! any panic, caught or not, so this target lets through exactly the panics raised while the
//! parquet and arrow crates are on the stack (which the guard turns into errors) and still
//! aborts on any other, ours included.
#![no_main]
use haptics_fuzz::scratch;

/// Chains onto libFuzzer's abort-on-panic hook: a panic raised while the parquet or arrow
/// crates are on the stack (located there, or in the standard library they called, e.g. a
/// `Vec::with_capacity` of a size read from the file) unwinds to rt-loop's guard; every other
/// panic still aborts (a finding). The backtrace is only taken when something panicked.
fn tolerate_parquet_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let file = info.location().map_or("", |l| l.file());
            let in_reader = |s: &str| s.contains("/parquet-") || s.contains("/arrow-");
            if !in_reader(file)
                && !in_reader(&std::backtrace::Backtrace::force_capture().to_string())
            {
                abort(info);
            }
        }));
    });
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    tolerate_parquet_panics();
    let Some((&pick, file)) = data.split_first() else {
        return;
    };
    let path = scratch(if pick & 1 == 0 {
        "recording.csv"
    } else {
        "recording.parquet"
    });
    std::fs::write(&path, file).expect("write scratch file");
    use rt_loop::record::read;
    if let Ok(names) = read::column_names(&path) {
        let wanted: Vec<&str> = names.iter().map(String::as_str).take(3).collect();
        if let Ok(cols) = read::read_columns(&path, &wanted) {
            assert_eq!(cols.len(), wanted.len());
            assert!(
                cols.iter().all(|c| c.len() == cols[0].len()),
                "ragged columns"
            );
        }
    }
    let _ = read::read_metadata(&path);
});
