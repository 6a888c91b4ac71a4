//! See fuzz/src/lib.rs: `text_config`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    scalpel_fuzz::text_config(data);
});
