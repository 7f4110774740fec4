//! The rings' protocols under arbitrary operation sequences, with a hostile writer poking the
//! shared words between operations (shm_ring_testing::fuzzing::rings).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| shm_ring_testing::fuzzing::rings(data));
