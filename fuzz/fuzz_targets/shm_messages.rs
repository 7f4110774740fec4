//! The shared-memory messages decoded from arbitrary slot words (shm_ring_testing::fuzzing::messages).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| shm_ring_testing::fuzzing::messages(data));
