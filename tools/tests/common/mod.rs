#![allow(dead_code)] // each test binary uses its part of the helpers
//! Helpers shared by the integration tests.

pub mod browser;
pub mod conformance;
pub mod lesson_session;
pub mod station;

/// Copies the folder `from` into `to` (created), subfolders included.
pub fn copy_tree(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}
