//! `rt-loop features` on a CSV series measured elsewhere (rt-loop's import): any file is
//! imported or refused with a reason (non-finite values, time not increasing, gaps, units),
//! never a panic; what is imported has every row's time finite and increasing.
#![no_main]
use haptics_fuzz::scratch;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let input = scratch("series.csv");
    let out = scratch("imported.csv");
    std::fs::write(&input, data).expect("write scratch file");
    let _ = std::fs::remove_file(&out);
    let options = rt_loop::import::ImportOptions {
        input,
        out: out.clone(),
        time_col: "t".into(),
        position_col: "x".into(),
        force_col: "f".into(),
        time_unit: None,
        position_unit: None,
        force_unit: None,
        g_v: None,
        g_a: None,
        contact_on_n: None,
        contact_off_n: None,
        max_gap_factor: rt_loop::import::DEFAULT_MAX_GAP_FACTOR,
        meters_per_count: 5e-6,
        extra_meta: None,
    };
    if rt_loop::import::import(&options).is_ok() {
        let cols = rt_loop::record::read::read_columns(&out, &["time"]).expect("read back");
        assert!(
            cols[0].iter().all(|t| t.is_finite()),
            "non-finite time imported"
        );
        assert!(
            cols[0].windows(2).all(|w| w[1] > w[0]),
            "time not increasing"
        );
    }
});
