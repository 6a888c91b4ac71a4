//! Reading a user's input file (a configuration, a scene, a mesh, a blade script): a
//! regular file only — a FIFO would block the reader forever, `/dev/zero` never ends — and
//! never more than a cap, counted while reading rather than trusted from the file's size.

use std::io::Read;
use std::path::Path;

/// Configurations and scene files are a few kB; this leaves room for comments.
pub const TOML_MAX_BYTES: u64 = 1 << 20;

/// A blade script: its 100 000 keyframes at most (`MAX_KEYFRAMES`) take about 6 MB as CSV
/// and 20 MB as TOML with every key on every keyframe.
pub const SCRIPT_MAX_BYTES: u64 = 32 << 20;

/// Fails unless `path` names a regular file (after symbolic links).
pub fn check_regular(path: &Path) -> std::io::Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path)?;
    if meta.is_file() {
        Ok(meta)
    } else {
        let kind = if meta.is_dir() {
            "a directory"
        } else {
            "a device, a pipe or a socket"
        };
        Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file: it is {kind}"),
        ))
    }
}

/// The bytes of the regular file `path`, failing if there are more than `max_bytes`.
pub fn read_capped(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    check_regular(path)?;
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("over the limit of {max_bytes} bytes"),
        ));
    }
    Ok(bytes)
}

/// [`read_capped`] as UTF-8 text.
pub fn read_text_capped(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    String::from_utf8(read_capped(path, max_bytes)?).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_oversized_files_are_refused() {
        let e = read_capped(Path::new("/dev/zero"), 10).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = read_capped(Path::new("/"), 10).unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        let dir = std::env::temp_dir().join(format!("scalpel-input-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("f.toml");
        std::fs::write(&file, "0123456789").unwrap();
        assert_eq!(read_capped(&file, 10).unwrap().len(), 10);
        let e = read_capped(&file, 9).unwrap_err();
        assert!(e.to_string().contains("over the limit of 9 bytes"), "{e}");
        std::fs::write(&file, [0xff, 0xfe]).unwrap();
        let e = read_text_capped(&file, 10).unwrap_err();
        assert!(e.to_string().contains("not UTF-8"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
