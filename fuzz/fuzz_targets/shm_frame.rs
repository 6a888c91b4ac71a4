//! See fuzz/src/lib.rs: `shm_frame`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    scalpel_fuzz::shm_frame(data);
});
