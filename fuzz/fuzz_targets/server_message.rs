//! See fuzz/src/lib.rs: `server_message`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    scalpel_fuzz::server_message(data);
});
