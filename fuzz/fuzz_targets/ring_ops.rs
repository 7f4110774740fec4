//! The rings' protocols under arbitrary operation sequences, with a hostile writer poking the
//! shared words between operations (haptics_proto::fuzzing::rings).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| haptics_proto::fuzzing::rings(data));
