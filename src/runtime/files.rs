//! Reading a file a user named: only a regular file (not a device, FIFO or directory,
//! which can be endless or block forever) and only up to a stated size, checked before
//! anything is read, so a path such as `/dev/zero` or a 40 GB file given by mistake
//! costs an error, not the machine's memory.

use std::io::Read;
use std::path::Path;

/// Largest configuration or character TOML file read, bytes (16 MiB: such files are a
/// few kilobytes; marker layouts of thousands of entries stay far below).
pub const MAX_TEXT_BYTES: u64 = 16 << 20;
/// Largest mesh, recording or cache file read, bytes (4 GiB).
pub const MAX_DATA_BYTES: u64 = 4 << 30;

/// The bytes of the regular file at `path`, if it holds at most `max_bytes`. The size is
/// checked on the open file before reading, and the read stops at `max_bytes + 1` in
/// case the file grows meanwhile. Errors are `std::io::Error`s of kind `InvalidInput`
/// (not a regular file, too large) or the open's and read's own.
pub fn read_bounded(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    // Judged before opening: opening a FIFO for reading blocks until a writer comes.
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a device, pipe or directory)",
        ));
    }
    let too_large = |len: u64| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{len} bytes, more than the {max_bytes} bytes read from such a file"),
        )
    };
    if meta.len() > max_bytes {
        return Err(too_large(meta.len()));
    }
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() || meta.len() > max_bytes {
        // Replaced between the two looks.
        return Err(too_large(meta.len()));
    }
    // The stated length bounds the buffer's first allocation; a file that grows while
    // it is read is cut at one byte past the limit and refused.
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// [`read_bounded`] as UTF-8 text (kind `InvalidData` when it is not).
pub fn read_text_bounded(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    String::from_utf8(read_bounded(path, max_bytes)?).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (byte {} starts an invalid sequence); a text file is expected here",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_large_files_are_refused_before_reading() {
        let e = read_bounded(Path::new("/dev/zero"), MAX_DATA_BYTES).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput, "{e}");
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let e = read_bounded(dir.path(), MAX_DATA_BYTES).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let p = dir.path().join("f");
        std::fs::write(&p, [7u8; 100]).unwrap();
        assert_eq!(read_bounded(&p, 100).unwrap(), vec![7u8; 100]);
        let e = read_bounded(&p, 99).unwrap_err();
        assert_eq!(
            e.to_string(),
            "100 bytes, more than the 99 bytes read from such a file"
        );
        // A FIFO with no writer: opening it would block forever.
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = read_bounded(&fifo, MAX_DATA_BYTES).unwrap_err();
            assert!(e.to_string().contains("not a regular file"), "{e}");
        } else {
            eprintln!("skipped the FIFO case: no mkfifo here");
        }
        std::fs::write(&p, [0xff, 0xfe]).unwrap();
        let e = read_text_bounded(&p, 100).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
    }
}
