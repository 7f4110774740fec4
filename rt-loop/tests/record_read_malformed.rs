//! A malformed Parquet recording is refused with an error, never a panic: the parquet crate
//! panics on these files (an `unwrap` in its thrift metadata decoder; a capacity overflow from a
//! length in the schema), found by the `recording` fuzz target (fuzz/corpus/recording/parquet-*:
//! the first byte picks the format, the rest is the file). rt-loop's reader contains the panic
//! (`parquet_guard`).

use rt_loop::record::read;

#[test]
fn parquet_files_that_make_the_parquet_crate_panic_are_refused_with_an_error() {
    refused(include_bytes!(
        "../../fuzz/corpus/recording/parquet-thrift-panic"
    ));
    refused(include_bytes!(
        "../../fuzz/corpus/recording/parquet-capacity-overflow"
    ));
}

fn refused(input: &[u8]) {
    let path = std::env::temp_dir().join(format!("malformed-{}.parquet", std::process::id()));
    std::fs::write(&path, &input[1..]).unwrap();
    let names = read::column_names(&path);
    let columns = read::read_columns(&path, &["time"]);
    let metadata = read::read_metadata(&path);
    let _ = std::fs::remove_file(&path);
    for (what, err) in [
        ("column_names", names.err()),
        ("read_columns", columns.err()),
        ("read_metadata", metadata.err()),
    ] {
        let err = err.unwrap_or_else(|| panic!("{what}: a malformed file must be refused"));
        assert!(
            err.to_string().contains("not a readable Parquet file") || what == "read_metadata",
            "{what}: {err}"
        );
    }
}
