//! Loggers: one task per stream, writing `<run>/<stream>.log` in the original's formats.
//!
//! In: records through a bounded channel per stream; producers use `try_send` only, so a slow
//! disk never slows the control path: what cannot be queued is dropped and counted.
//! Out: the stream's file, written in batches and flushed when the stream closes.
//! Ends: when every sender is gone and the queue is drained.

use crate::logs::{PerStream, Record, Stream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

/// A logger that stops writing for a while once it has written some records (fault injection
/// for tests and the simulator: a stalled disk).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogStall {
    pub stream: Stream,
    pub after_records: u64,
    pub duration: Duration,
}

/// The producers' side: cheap to clone, never blocks.
#[derive(Debug, Clone)]
pub struct LogHub {
    senders: Vec<mpsc::Sender<Record>>,
    dropped: Arc<[AtomicU64; 7]>,
}

impl LogHub {
    /// Queues a record; when the stream's queue is full the record is dropped and counted.
    pub fn log(&self, rec: Record) {
        let i = rec.stream() as usize;
        if let Some(tx) = self.senders.get(i)
            && tx.try_send(rec).is_err()
        {
            self.dropped[i].fetch_add(1, Ordering::Relaxed);
        }
    }

    pub fn err(&self, line: impl Into<String>) {
        self.log(Record::note(line));
    }

    /// Dropped records per stream.
    pub fn dropped(&self) -> PerStream<u64> {
        PerStream(std::array::from_fn(|i| {
            self.dropped[i].load(Ordering::Relaxed)
        }))
    }
}

/// What a logger wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggerReport {
    pub stream: Stream,
    pub records: u64,
    pub path: PathBuf,
}

/// Creates the stream files in `dir` and spawns one logger task per stream on the current
/// runtime.
pub async fn spawn_all(
    dir: &Path,
    capacity: usize,
    stall: Option<LogStall>,
) -> std::io::Result<(
    LogHub,
    Vec<tokio::task::JoinHandle<std::io::Result<LoggerReport>>>,
)> {
    let mut senders = Vec::new();
    let mut handles = Vec::new();
    for stream in Stream::ALL {
        let path = dir.join(format!("{}.log", stream.name()));
        let file = tokio::fs::File::create(&path).await?;
        let (tx, rx) = mpsc::channel(capacity);
        senders.push(tx);
        let stall = stall.filter(|s| s.stream == stream);
        handles.push(tokio::spawn(run(stream, path, file, rx, stall)));
    }
    Ok((
        LogHub {
            senders,
            dropped: Arc::new(std::array::from_fn(|_| AtomicU64::new(0))),
        },
        handles,
    ))
}

/// Bytes gathered before a write.
const BATCH_BYTES: usize = 64 * 1024;

async fn run(
    stream: Stream,
    path: PathBuf,
    file: tokio::fs::File,
    mut rx: mpsc::Receiver<Record>,
    mut stall: Option<LogStall>,
) -> std::io::Result<LoggerReport> {
    let mut out = tokio::io::BufWriter::new(file);
    let mut buf = String::with_capacity(BATCH_BYTES + 1024);
    let mut records = 0u64;
    while let Some(rec) = rx.recv().await {
        rec.write(&mut buf);
        records += 1;
        // Take what else is queued before touching the file.
        while buf.len() < BATCH_BYTES {
            match rx.try_recv() {
                Ok(r) => {
                    r.write(&mut buf);
                    records += 1;
                }
                Err(_) => break,
            }
        }
        if let Some(s) = stall
            && records >= s.after_records
        {
            tracing::warn!(
                stream = stream.name(),
                ms = s.duration.as_millis() as u64,
                "log writes stalled"
            );
            tokio::time::sleep(s.duration).await;
            stall = None;
        }
        out.write_all(buf.as_bytes()).await?;
        buf.clear();
    }
    out.flush().await?;
    Ok(LoggerReport {
        stream,
        records,
        path,
    })
}
