//! The shared-memory messages decoded from arbitrary slot words (haptics_proto::fuzzing::messages).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| haptics_proto::fuzzing::messages(data));
