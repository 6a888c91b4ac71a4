//! See fuzz/src/lib.rs: `client_message`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    scalpel_fuzz::client_message(data);
});
