//! Every file uquad reads whole, read with bounds: a regular file only (a FIFO would hold the
//! start forever, a device such as /dev/zero never ends, a directory is no file), at most a
//! size per kind of file, said in the error, and UTF-8 text. A link is followed; a link to
//! nothing is an error, not a missing file. Not in the original's spec (its files were read
//! with `fscanf` until they ended).

use std::io::Read;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// What a file is to uquad; each kind has its own size limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// A configuration profile (`--config`).
    Profile,
    /// The parameters a ground station set (`params.toml`).
    Parameters,
    /// The IMU's calibration (`imu.calib_file`).
    Calibration,
    /// A gain or LQR weight file (a few numbers).
    Numbers,
    /// A mission (`--mission`, or one a ground station uploaded).
    Mission,
    /// A stream of a run folder read back whole (mode.log, a replay's inputs).
    RunLog,
}

impl FileKind {
    /// The kind's name in an error.
    pub fn name(self) -> &'static str {
        match self {
            FileKind::Profile => "a profile",
            FileKind::Parameters => "a parameters file",
            FileKind::Calibration => "a calibration file",
            FileKind::Numbers => "a gains file",
            FileKind::Mission => "a mission",
            FileKind::RunLog => "a run's log read whole",
        }
    }

    /// The largest such file read, bytes: far above any real one (the default profile is
    /// 30 kB, a calibration 1 kB, a 2 000-waypoint mission 200 kB), far below what would take
    /// the machine's memory. A run's largest stream, x_hat.log, grows about 85 MB an hour
    /// flown: `plot` and `export`, which still read a stream whole, refuse runs of more than
    /// about three hours.
    pub fn limit_bytes(self) -> u64 {
        match self {
            FileKind::Profile | FileKind::Parameters => 1 << 20,
            FileKind::Calibration | FileKind::Numbers => 1 << 16,
            FileKind::Mission => 8 << 20,
            FileKind::RunLog => 256 << 20,
        }
    }
}

/// Why a file could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadError {
    /// The file does not exist (a link to nothing is not missing: it is an error).
    pub missing: bool,
    /// What is wrong with it, without its path (the caller names it).
    pub reason: String,
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.reason)
    }
}

impl std::error::Error for ReadError {}

fn refused(reason: String) -> ReadError {
    ReadError {
        missing: false,
        reason,
    }
}

/// The text of `path`, a file of `kind`.
pub fn read_text(path: &Path, kind: FileKind) -> Result<String, ReadError> {
    let mut file = open(path)?;
    let meta = file
        .metadata()
        .map_err(|e| refused(format!("cannot read it: {e}")))?;
    let ft = meta.file_type();
    if !ft.is_file() {
        return Err(refused(format!("{}, not a regular file", type_name(&ft))));
    }
    let limit = kind.limit_bytes();
    let too_big =
        |size: String| refused(format!("{size}; {} is at most {limit} bytes", kind.name()));
    if meta.len() > limit {
        return Err(too_big(format!("{} bytes", meta.len())));
    }
    // The file may grow between the look and the read: never more than the limit is read.
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    (&mut file)
        .take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| refused(format!("cannot read it: {e}")))?;
    if bytes.len() as u64 > limit {
        return Err(too_big("more than that, grown while read".to_string()));
    }
    String::from_utf8(bytes).map_err(|e| {
        refused(format!(
            "not UTF-8 text (byte {} is not)",
            e.utf8_error().valid_up_to()
        ))
    })
}

/// `path` open for reading a piece at a time (a log streamed by `export`): a regular file
/// only, refused like [`read_text`] refuses (a FIFO, a device, a folder, a link to
/// nothing); no size limit, the reader bounds what it holds.
pub fn open_regular(path: &Path) -> Result<std::fs::File, ReadError> {
    let file = open(path)?;
    let meta = file
        .metadata()
        .map_err(|e| refused(format!("cannot read it: {e}")))?;
    if !meta.file_type().is_file() {
        return Err(refused(format!(
            "{}, not a regular file",
            type_name(&meta.file_type())
        )));
    }
    Ok(file)
}

/// Whether `path` names anything, a link to nothing included.
pub fn exists(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

/// Opens without waiting (a FIFO opened for reading would wait for a writer) and without
/// taking a terminal for the process's own.
fn open(path: &Path) -> Result<std::fs::File, ReadError> {
    let opened = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path);
    opened.map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound if exists(path) => {
            let target = std::fs::read_link(path)
                .map(|t| t.display().to_string())
                .unwrap_or_default();
            refused(format!("a link to {target:?}, which does not exist"))
        }
        std::io::ErrorKind::NotFound => ReadError {
            missing: true,
            reason: "no such file".to_string(),
        },
        _ => refused(format!("cannot open it: {e}")),
    })
}

fn type_name(ft: &std::fs::FileType) -> &'static str {
    if ft.is_dir() {
        "a directory"
    } else if ft.is_fifo() {
        "a FIFO"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_within_their_limit_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let ok = dir.path().join("ok.toml");
        std::fs::write(&ok, "a = 1\n").unwrap();
        assert_eq!(read_text(&ok, FileKind::Profile).unwrap(), "a = 1\n");
        let missing = read_text(&dir.path().join("none"), FileKind::Profile).unwrap_err();
        assert!(missing.missing, "{missing}");
        // A directory, a device, a FIFO: refused at once, naming what they are.
        let e = read_text(dir.path(), FileKind::Profile).unwrap_err();
        assert!(!e.missing && e.reason.contains("a directory"), "{e}");
        let e = read_text(Path::new("/dev/zero"), FileKind::Calibration).unwrap_err();
        assert!(e.reason.contains("a character device"), "{e}");
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read_text(&fifo, FileKind::Parameters).unwrap_err();
        assert!(e.reason.contains("a FIFO"), "{e}");
        // Over the kind's limit: the size and the limit said.
        let big = dir.path().join("big.txt");
        std::fs::write(
            &big,
            vec![b'1'; (FileKind::Numbers.limit_bytes() + 1) as usize],
        )
        .unwrap();
        let e = read_text(&big, FileKind::Numbers).unwrap_err();
        assert!(e.reason.contains("at most 65536 bytes"), "{e}");
        // A link to nothing is not a missing file.
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(dir.path().join("gone"), &link).unwrap();
        let e = read_text(&link, FileKind::Parameters).unwrap_err();
        assert!(!e.missing && e.reason.contains("does not exist"), "{e}");
        assert!(exists(&link));
        // Not text.
        let bin = dir.path().join("bin");
        std::fs::write(&bin, [0x61, 0xff, 0x62]).unwrap();
        let e = read_text(&bin, FileKind::Mission).unwrap_err();
        assert!(e.reason.contains("byte 1"), "{e}");
    }
}
