//! rt-loop's run configuration: any text is parsed to a config or refused, and a parsed one
//! is validated (refused with a reason or accepted), never a panic.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(cfg) = rt_loop::config::RunConfig::from_toml(text) {
        let _ = cfg.validate();
    }
});
