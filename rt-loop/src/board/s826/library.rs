//! Finding and loading the vendor's library at run time (`libloading`): `--s826-lib PATH`,
//! else `HAPTICS_S826_LIB`, else `lib826_64.so` on the usual library paths (the dynamic
//! loader's search: LD_LIBRARY_PATH, ld.so.cache, /lib, /usr/lib) and /usr/local/lib. Every
//! symbol is resolved once here into a plain function pointer, so a step's calls look nothing
//! up. A machine without the library builds and runs everything else; asking for the board
//! there gives one sentence saying what is missing and how to install it.

use super::api::*;
use crate::board::BoardError;
use std::path::{Path, PathBuf};

/// The library's file name on Linux (Sensoray's SDK, 64-bit).
pub const LIB_NAME: &str = "lib826_64.so";
/// The environment variable naming the library.
pub const LIB_ENV: &str = "HAPTICS_S826_LIB";

/// The loaded library and the functions this driver calls (kept alive together).
pub struct S826Lib {
    pub path: String,
    pub system_open: SystemOpenFn,
    pub system_close: SystemCloseFn,
    pub version_read: VersionReadFn,
    pub counter_mode_write: CounterModeWriteFn,
    pub counter_state_write: CounterStateWriteFn,
    pub counter_snapshot_config_write: CounterSnapshotConfigWriteFn,
    pub counter_snapshot: CounterSnapshotFn,
    pub counter_snapshot_read: CounterSnapshotReadFn,
    pub counter_preload_write: CounterPreloadWriteFn,
    pub counter_preload: CounterPreloadFn,
    pub dac_range_write: DacRangeWriteFn,
    pub dac_data_write: DacDataWriteFn,
    pub safe_wren_write: SafeWrenWriteFn,
    pub safe_control_write: SafeControlWriteFn,
    pub safe_control_read: SafeControlReadFn,
    pub watchdog_config_write: WatchdogConfigWriteFn,
    pub watchdog_enable_write: WatchdogEnableWriteFn,
    pub watchdog_kick: WatchdogKickFn,
    pub watchdog_event_wait: WatchdogEventWaitFn,
    // Last: the function pointers above are only valid while this is loaded.
    _lib: libloading::Library,
}

/// The sentence for a machine without the library.
pub fn missing_sentence(tried: &str) -> String {
    format!(
        "the Sensoray 826 library {LIB_NAME} was not found ({tried}): install Sensoray's 826 \
         Linux SDK (its kernel driver and {LIB_NAME}, see docs/lab.md), or name the library \
         with --s826-lib PATH or {LIB_ENV}"
    )
}

impl S826Lib {
    /// Loads the library: `explicit` (`--s826-lib`), else `HAPTICS_S826_LIB`, else the usual
    /// library paths.
    pub fn load(explicit: Option<&Path>) -> Result<S826Lib, BoardError> {
        let from_env = std::env::var_os(LIB_ENV)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from);
        match explicit.map(Path::to_path_buf).or(from_env) {
            Some(p) => {
                if !p.exists() {
                    return Err(BoardError::Missing(missing_sentence(&format!(
                        "{} does not exist",
                        p.display()
                    ))));
                }
                Self::open(&p.display().to_string())
            }
            None => {
                let mut tried = Vec::new();
                for name in [LIB_NAME.to_string(), format!("/usr/local/lib/{LIB_NAME}")] {
                    match Self::open(&name) {
                        Ok(l) => return Ok(l),
                        Err(BoardError::Missing(_)) => tried.push(name),
                        Err(e) => return Err(e),
                    }
                }
                Err(BoardError::Missing(missing_sentence(&format!(
                    "tried {}, --s826-lib and {LIB_ENV} unset",
                    tried.join(", ")
                ))))
            }
        }
    }

    fn open(name: &str) -> Result<S826Lib, BoardError> {
        // SAFETY: loading runs the library's initialisers; the 826 library has none with
        // preconditions on this process.
        let lib = unsafe { libloading::Library::new(name) }.map_err(|e| {
            BoardError::Missing(missing_sentence(&format!(
                "{name} could not be loaded: {e}"
            )))
        })?;
        macro_rules! sym {
            ($t:ty, $name:literal) => {{
                // SAFETY: the type is the one 826api.h declares for this symbol.
                let s = unsafe { lib.get::<$t>($name) }.map_err(|e| BoardError::Refused {
                    step: "loading the 826 library",
                    why: format!(
                        "{name} has no symbol {} ({e}): is it Sensoray's 826 library?",
                        String::from_utf8_lossy(&$name[..$name.len() - 1])
                    ),
                })?;
                *s
            }};
        }
        Ok(S826Lib {
            path: name.to_string(),
            system_open: sym!(SystemOpenFn, b"S826_SystemOpen\0"),
            system_close: sym!(SystemCloseFn, b"S826_SystemClose\0"),
            version_read: sym!(VersionReadFn, b"S826_VersionRead\0"),
            counter_mode_write: sym!(CounterModeWriteFn, b"S826_CounterModeWrite\0"),
            counter_state_write: sym!(CounterStateWriteFn, b"S826_CounterStateWrite\0"),
            counter_snapshot_config_write: sym!(
                CounterSnapshotConfigWriteFn,
                b"S826_CounterSnapshotConfigWrite\0"
            ),
            counter_snapshot: sym!(CounterSnapshotFn, b"S826_CounterSnapshot\0"),
            counter_snapshot_read: sym!(CounterSnapshotReadFn, b"S826_CounterSnapshotRead\0"),
            counter_preload_write: sym!(CounterPreloadWriteFn, b"S826_CounterPreloadWrite\0"),
            counter_preload: sym!(CounterPreloadFn, b"S826_CounterPreload\0"),
            dac_range_write: sym!(DacRangeWriteFn, b"S826_DacRangeWrite\0"),
            dac_data_write: sym!(DacDataWriteFn, b"S826_DacDataWrite\0"),
            safe_wren_write: sym!(SafeWrenWriteFn, b"S826_SafeWrenWrite\0"),
            safe_control_write: sym!(SafeControlWriteFn, b"S826_SafeControlWrite\0"),
            safe_control_read: sym!(SafeControlReadFn, b"S826_SafeControlRead\0"),
            watchdog_config_write: sym!(WatchdogConfigWriteFn, b"S826_WatchdogConfigWrite\0"),
            watchdog_enable_write: sym!(WatchdogEnableWriteFn, b"S826_WatchdogEnableWrite\0"),
            watchdog_kick: sym!(WatchdogKickFn, b"S826_WatchdogKick\0"),
            watchdog_event_wait: sym!(WatchdogEventWaitFn, b"S826_WatchdogEventWait\0"),
            _lib: lib,
        })
    }
}
