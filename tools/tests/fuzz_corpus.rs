//! Replays the cargo-fuzz corpora (fuzz/corpus/<target>/) through the same entry points
//! the fuzz targets call (fuzz/src/lib.rs), on stable, in every test run: a decoder that
//! panics, aborts or runs away on an input the fuzzer once found fails here. Growing the
//! corpora: `cargo +nightly fuzz run <target> fuzz/corpus/<target>` (docs/PROTOCOL.md).

#[path = "../../fuzz/src/lib.rs"]
mod fuzz_inputs;

use std::path::Path;

#[test]
fn every_corpus_input_decodes_or_is_refused() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus");
    type Decoder = fn(&[u8]);
    let targets: [(&str, Decoder); 5] = [
        ("client_message", fuzz_inputs::client_message),
        ("server_message", fuzz_inputs::server_message),
        ("shm_frame", fuzz_inputs::shm_frame),
        ("mesh", fuzz_inputs::mesh),
        ("text_config", fuzz_inputs::text_config),
    ];
    for (target, decode) in targets {
        let dir = corpus.join(target);
        let mut inputs = 0;
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            decode(&bytes);
            inputs += 1;
        }
        assert!(inputs > 0, "{target}: empty corpus");
    }
}
