//! The log download's file work, on a blocking worker: the run folders beside this run's
//! (the newest [`LOGS_MAX`]), each exported as a ULog file into `.exports` in the log folder
//! (a finished run once; the running one afresh at every list, as it stands; exports of
//! runs no longer listed are removed), and a listed export read whole for the link (at most
//! [`LOG_BYTES_MAX`]). The link asks for one list and one read at a time.

use crate::gcs::connection::LogEntry;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Runs listed, the newest.
pub const LOGS_MAX: usize = 20;
/// A log larger than this is listed but not sent (LOG_ENTRY's size is 32 bits; the link
/// holds a log being sent in memory).
pub const LOG_BYTES_MAX: u64 = 256 << 20;

/// Exports a run folder as a ULog file at a path (the app's `uquad export`), or says why not.
pub type Export = Arc<dyn Fn(&Path, &Path) -> Result<(), String> + Send + Sync>;

/// What the link needs to serve logs.
#[derive(Clone)]
pub struct LogDesk {
    /// The folder holding the run folders, and this run's.
    pub dir: PathBuf,
    pub run_dir: PathBuf,
    pub export: Export,
    /// Where exports are kept.
    pub cache: PathBuf,
    /// The exports of the last list, by id (1-based).
    listed: Arc<Mutex<Vec<PathBuf>>>,
}

impl LogDesk {
    /// Logs of the runs under `dir` (this one `run_dir`), exported into `dir/.exports`.
    pub fn new(dir: PathBuf, run_dir: PathBuf, export: Export) -> Self {
        let cache = dir.join(".exports");
        LogDesk {
            dir,
            run_dir,
            export,
            cache,
            listed: Arc::default(),
        }
    }

    /// The logs, oldest first: each run folder's export (made when missing, or for the
    /// running one); a run that cannot be exported (no estimate yet, unreadable) is left out.
    pub fn list(&self) -> Result<Vec<LogEntry>, String> {
        std::fs::create_dir_all(&self.cache)
            .map_err(|e| format!("cannot create {}: {e}", self.cache.display()))?;
        let mut entries = Vec::new();
        let mut listed = Vec::new();
        for run in self.runs()? {
            let name = run.file_name().map(|n| n.to_string_lossy().to_string());
            let out = self.cache.join(format!("{}.ulg", name.unwrap_or_default()));
            let fresh = run == self.run_dir || !out.is_file();
            if fresh && (self.export)(&run, &out).is_err() {
                continue;
            }
            let Ok(meta) = std::fs::metadata(&out) else {
                continue;
            };
            listed.push(out);
            entries.push(LogEntry {
                id: listed.len() as u16,
                size: meta.len().min(u64::from(u32::MAX)) as u32,
                time_utc: started_utc(&run),
            });
        }
        self.prune(&listed);
        if let Ok(mut l) = self.listed.lock() {
            *l = listed;
        }
        Ok(entries)
    }

    /// Log `id` of the last list, whole.
    pub fn read(&self, id: u16) -> Result<Arc<[u8]>, String> {
        let path = self
            .listed
            .lock()
            .ok()
            .and_then(|l| l.get(usize::from(id).wrapping_sub(1)).cloned())
            .ok_or_else(|| format!("no log {id}"))?;
        let size = std::fs::metadata(&path).map_or(0, |m| m.len());
        if size > LOG_BYTES_MAX {
            return Err(format!(
                "{size} bytes, over the {LOG_BYTES_MAX} a download sends"
            ));
        }
        std::fs::read(&path)
            .map(Arc::from)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))
    }

    /// Removes the exports of runs no longer listed (the cache holds the listed ones only).
    fn prune(&self, listed: &[PathBuf]) {
        let Ok(read) = std::fs::read_dir(&self.cache) else {
            return;
        };
        for e in read.flatten() {
            let path = e.path();
            if !listed.contains(&path) {
                let _ = std::fs::remove_file(&path);
            }
        }
    }

    /// The newest [`LOGS_MAX`] run folders (those with a mode.log), oldest first: their
    /// names begin with the start time, so by name is by age.
    fn runs(&self) -> Result<Vec<PathBuf>, String> {
        let read = std::fs::read_dir(&self.dir)
            .map_err(|e| format!("cannot list {}: {e}", self.dir.display()))?;
        let mut runs: Vec<PathBuf> = read
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.join("mode.log").is_file())
            .collect();
        runs.sort();
        let skip = runs.len().saturating_sub(LOGS_MAX);
        Ok(runs.split_off(skip))
    }
}

/// When run `run` began, s since 1970: its configuration was written then (0: unknown).
fn started_utc(run: &Path) -> u32 {
    std::fs::metadata(run.join("config.toml"))
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_secs().min(u64::from(u32::MAX)) as u32)
}
