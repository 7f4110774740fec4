//! A segment header as an attacher finds it: validation refuses or accepts a layout that
//! places every ring inside the file (haptics_proto::fuzzing::header).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| haptics_proto::fuzzing::header(data));
