//! The one way a file the user names is read: a regular file only (a FIFO would block for
//! ever, a device such as `/dev/zero` never ends), at most a given size, as UTF-8 text, every
//! error naming the file. Scenario files, their trace files and trace folders, netem's
//! `--profile-file`, `hilbench trace`'s imports, the TLS flags' files, the gateway's MAVLink
//! signing key and `sweep-merge`'s shard files all read through [`read_text`] or
//! [`read_bytes`]; `controller solve FILE` checks [`check_regular`] and reads a line at a time.

use std::io::Read;
use std::path::{Path, PathBuf};

/// Largest scenario file, bytes. A scenario with a trace of a million delays inline (what a
/// run writes as flown) is about 20 MB.
pub const MAX_SCENARIO_FILE_BYTES: u64 = 64 << 20;
/// Largest trace file, bytes: a million delays in `delay::write_trace`'s format are about
/// 10 MB.
pub const MAX_TRACE_FILE_BYTES: u64 = 64 << 20;
/// Largest certificate or key file (PEM), bytes.
pub const MAX_PEM_FILE_BYTES: u64 = 1 << 20;
/// Most files a sweep's trace folder (`dir`) may hold.
pub const MAX_TRACE_DIR_FILES: usize = 10_000;
/// Most bytes of all the files of one trace folder.
pub const MAX_TRACE_DIR_BYTES: u64 = 512 << 20;

/// Why a file could not be read: the file, and the reason (`Display`: `path: reason`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {reason}", path.display())]
pub struct ReadError {
    pub path: PathBuf,
    pub reason: String,
}

/// The text of the regular file `path`, at most `max_bytes` long; `what` says what the file
/// is in the error about its size (`"a scenario"`).
pub fn read_text(path: &Path, max_bytes: u64, what: &str) -> Result<String, ReadError> {
    let bytes = read_bytes(path, max_bytes, what)?;
    String::from_utf8(bytes).map_err(|e| ReadError {
        path: path.to_path_buf(),
        reason: format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
    })
}

/// The bytes of the regular file `path`, at most `max_bytes` of them (see [`read_text`]).
pub fn read_bytes(path: &Path, max_bytes: u64, what: &str) -> Result<Vec<u8>, ReadError> {
    let error = |reason: String| ReadError { path: path.to_path_buf(), reason };
    let io = |e: std::io::Error| error(format!("cannot read it: {e}"));
    // Looked at before opening it: opening a FIFO for reading blocks until a writer comes.
    let meta = std::fs::metadata(path).map_err(io)?;
    check_regular(&meta).map_err(error)?;
    let file = std::fs::File::open(path).map_err(io)?;
    // And again what was opened (the path may have changed in between).
    let meta = file.metadata().map_err(io)?;
    check_regular(&meta).map_err(error)?;
    let too_big = |len: u64| {
        error(format!("{len} bytes or more, more than the {} a file of {what} may hold", size(max_bytes)))
    };
    if meta.len() > max_bytes {
        return Err(too_big(meta.len()));
    }
    // A file that grows while it is read stops at the cap all the same.
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Refuses anything but a regular file (a directory, a FIFO, a socket, a device): the reason.
pub fn check_regular(meta: &std::fs::Metadata) -> Result<(), String> {
    if meta.is_file() {
        return Ok(());
    }
    let kind = if meta.is_dir() { "a directory" } else { "not a regular file (a device, FIFO or socket)" };
    Err(format!("{kind}; only a regular file is read"))
}

/// `bytes` as MiB (or bytes when less).
fn size(bytes: u64) -> String {
    if bytes >= 1 << 20 { format!("{} MiB", bytes >> 20) } else { format!("{bytes} bytes") }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("hilbench-user-file-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        dir
    }

    #[test]
    fn a_device_a_directory_and_a_fifo_are_refused_without_reading_and_a_big_file_is_refused_by_size() {
        let e = read_text(Path::new("/dev/zero"), 1 << 20, "a trace").expect_err("/dev/zero").to_string();
        assert!(e.contains("/dev/zero") && e.contains("not a regular file"), "{e}");
        let dir = temp_dir("kinds");
        let e = read_text(&dir, 1 << 20, "a trace").expect_err("a directory").to_string();
        assert!(e.contains("a directory"), "{e}");
        #[cfg(unix)]
        {
            let fifo = dir.join("fifo");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                // Opening it would block: refused before it is opened.
                let e = read_text(&fifo, 1 << 20, "a trace").expect_err("a FIFO").to_string();
                assert!(e.contains("not a regular file"), "{e}");
            }
        }
        let big = dir.join("big.csv");
        std::fs::write(&big, vec![b'1'; 2048]).expect("write");
        let e = read_text(&big, 1024, "a trace").expect_err("too big").to_string();
        assert!(e.contains("big.csv") && e.contains("1024 bytes") && e.contains("a trace"), "{e}");
        assert_eq!(read_text(&big, 2048, "a trace").map(|t| t.len()), Ok(2048));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
