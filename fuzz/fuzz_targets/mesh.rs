//! See fuzz/src/lib.rs: `mesh`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    scalpel_fuzz::mesh(data);
});
