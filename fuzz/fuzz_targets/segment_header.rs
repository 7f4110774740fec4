//! A segment header as an attacher finds it: validation refuses or accepts a layout that
//! places every ring inside the file (shm_ring_testing::fuzzing::header).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| shm_ring_testing::fuzzing::header(data));
