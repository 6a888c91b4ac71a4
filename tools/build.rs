//! `sqlx::migrate!` embeds tools/migrations at compile time: a new or edited migration must
//! rebuild the binary.
fn main() {
    println!("cargo:rerun-if-changed=migrations");
}
