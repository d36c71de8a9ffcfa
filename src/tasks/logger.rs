//! Loggers: one task per stream, writing `<run>/<stream>.log` in the original's formats.
//!
//! In: records through a bounded channel per stream; producers use `try_send` only, so a slow
//! disk never slows the control path: what cannot be queued is dropped and counted. Loggers
//! take their queue every 10 ms rather than being woken per record, so queuing one wakes no
//! thread.
//! Out: the stream's file, written in batches. err.log and gps.log (what an operator reads
//! after a crash: the start-up, the halts, the fixes) reach the kernel after every batch and
//! the disk at most a second later (`sync_data`), so a killed process or a power cut loses at
//! most a second of them; the other streams reach the kernel at least once a second. A write
//! that fails (a full disk) loses its batch, counted as dropped and as a write error of the
//! stream, and the logger goes on with the next.
//! Ends: when every sender is gone and the queue is drained.

use crate::logs::{PerStream, Record, Stream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

/// One counter per stream, shared by the producers and the loggers.
type Counters = Arc<[AtomicU64; Stream::COUNT]>;

/// A logger that stops writing for a while once it has written some records (fault injection
/// for tests and the simulator: a stalled disk).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogStall {
    pub stream: Stream,
    pub after_records: u64,
    /// And not before this instant (the simulator's `log-stall@T`).
    pub not_before: Option<Instant>,
    pub duration: Duration,
}

/// The producers' side: cheap to clone, never blocks.
#[derive(Debug, Clone)]
pub struct LogHub {
    senders: Vec<mpsc::Sender<Record>>,
    dropped: Counters,
    io_errors: Counters,
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

    /// Dropped records per stream (a full queue, or a failed write).
    pub fn dropped(&self) -> PerStream<u64> {
        PerStream(std::array::from_fn(|i| {
            self.dropped[i].load(Ordering::Relaxed)
        }))
    }

    /// Failed writes per stream (an I/O error, a full disk).
    pub fn io_errors(&self) -> PerStream<u64> {
        PerStream(std::array::from_fn(|i| {
            self.io_errors[i].load(Ordering::Relaxed)
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
    let dropped: Counters = Arc::new(std::array::from_fn(|_| AtomicU64::new(0)));
    let io_errors: Counters = Arc::new(std::array::from_fn(|_| AtomicU64::new(0)));
    for stream in Stream::ALL {
        let path = dir.join(format!("{}.log", stream.name()));
        let file = tokio::fs::File::create(&path).await?;
        let (tx, rx) = mpsc::channel(capacity);
        senders.push(tx);
        let w = StreamWriter {
            stream,
            file,
            stall: stall.filter(|s| s.stream == stream),
            dropped: dropped.clone(),
            io_errors: io_errors.clone(),
            flushed: Instant::now(),
            synced: Instant::now(),
            lost: 0,
        };
        handles.push(tokio::spawn(run(w, path, rx)));
    }
    Ok((
        LogHub {
            senders,
            dropped,
            io_errors,
        },
        handles,
    ))
}

/// Bytes gathered before a write.
const BATCH_BYTES: usize = 64 * 1024;

/// How often a stream reaches the kernel at least, and err.log and gps.log the disk.
const FLUSH_EVERY: Duration = Duration::from_secs(1);

/// How often a logger takes what is queued.
const POLL: Duration = Duration::from_millis(10);

/// One stream's file and its bookkeeping.
struct StreamWriter {
    stream: Stream,
    file: tokio::fs::File,
    stall: Option<LogStall>,
    dropped: Counters,
    io_errors: Counters,
    /// When the stream last reached the kernel, and the disk.
    flushed: Instant,
    synced: Instant,
    /// Records lost in failed writes.
    lost: u64,
}

impl StreamWriter {
    /// The streams read after a crash: each batch reaches the kernel at once.
    fn durable(&self) -> bool {
        matches!(self.stream, Stream::Err | Stream::Gps)
    }

    /// Writes `buf` (holding `records` more records) when due or `force`d: at once for the
    /// durable streams, else once it is large or a second old; a failed write drops the
    /// batch, counted.
    async fn write(&mut self, buf: &mut String, records: u64, pending: &mut u64, force: bool) {
        *pending += records;
        let due = force
            || self.durable()
            || buf.len() >= BATCH_BYTES
            || self.flushed.elapsed() >= FLUSH_EVERY;
        if !due || buf.is_empty() {
            return;
        }
        let i = self.stream as usize;
        // tokio's File completes a write in the background: the flush waits for it, so that a
        // failure is counted against the batch that failed.
        let written = match self.file.write_all(buf.as_bytes()).await {
            Ok(()) => self.file.flush().await,
            Err(e) => Err(e),
        };
        if let Err(e) = written {
            if self.io_errors[i].fetch_add(1, Ordering::Relaxed) == 0 {
                tracing::error!(stream = self.stream.name(), "log write failed: {e}");
            }
            self.dropped[i].fetch_add(*pending, Ordering::Relaxed);
            self.lost += *pending;
        }
        buf.clear();
        *pending = 0;
        self.flushed = Instant::now();
        if self.durable() && self.synced.elapsed() >= FLUSH_EVERY {
            self.sync().await;
        }
    }

    async fn sync(&mut self) {
        if let Err(e) = self.file.sync_data().await {
            let i = self.stream as usize;
            if self.io_errors[i].fetch_add(1, Ordering::Relaxed) == 0 {
                tracing::error!(stream = self.stream.name(), "log sync failed: {e}");
            }
        }
        self.synced = Instant::now();
    }

    /// Fault injection: the stream's writes block once, after `after_records`.
    async fn maybe_stall(&mut self, records: u64) {
        if let Some(s) = self.stall
            && records >= s.after_records
            && s.not_before.is_none_or(|t| Instant::now() >= t)
        {
            tracing::warn!(
                stream = self.stream.name(),
                ms = s.duration.as_millis() as u64,
                "log writes stalled"
            );
            tokio::time::sleep(s.duration).await;
            self.stall = None;
        }
    }
}

async fn run(
    mut w: StreamWriter,
    path: PathBuf,
    mut rx: mpsc::Receiver<Record>,
) -> std::io::Result<LoggerReport> {
    // Records are formatted into `buf`; `pending` of them are not yet written.
    let mut buf = String::with_capacity(BATCH_BYTES + 1024);
    let (mut records, mut pending) = (0u64, 0u64);
    // The logger looks at its queue every `POLL` instead of being woken by each record: a
    // record queued from the control path then wakes no thread (no futex, no system call on
    // the way to the motors). The queue holds `log.queue_records` records, seconds of a
    // 100 Hz stream.
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        let mut batch = 0;
        let mut closed = false;
        while buf.len() < BATCH_BYTES {
            match rx.try_recv() {
                Ok(r) => {
                    r.write(&mut buf);
                    batch += 1;
                }
                Err(mpsc::error::TryRecvError::Empty) => break,
                Err(mpsc::error::TryRecvError::Disconnected) => {
                    closed = true;
                    break;
                }
            }
        }
        records += batch;
        if batch > 0 {
            w.maybe_stall(records).await;
        }
        // Written when due: a large batch, a durable stream, or a second since the last write.
        w.write(&mut buf, batch, &mut pending, false).await;
        if closed {
            break;
        }
    }
    // The end of the run: everything to the kernel, the durable streams to the disk.
    w.write(&mut buf, 0, &mut pending, true).await;
    if w.durable() {
        w.sync().await;
    }
    Ok(LoggerReport {
        stream: w.stream,
        records: records - w.lost.min(records),
        path,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_full_disk_loses_records_counted_and_the_logger_goes_on() {
        // /dev/full refuses every write with ENOSPC, as a full disk does.
        let Ok(file) = tokio::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .await
        else {
            return;
        };
        let (dropped, io_errors): (Counters, Counters) = (
            Arc::new(std::array::from_fn(|_| AtomicU64::new(0))),
            Arc::new(std::array::from_fn(|_| AtomicU64::new(0))),
        );
        let w = StreamWriter {
            stream: Stream::Err,
            file,
            stall: None,
            dropped: dropped.clone(),
            io_errors: io_errors.clone(),
            flushed: Instant::now(),
            synced: Instant::now(),
            lost: 0,
        };
        let (tx, rx) = mpsc::channel(16);
        let logger = tokio::spawn(run(w, PathBuf::from("/dev/full"), rx));
        for k in 0..10 {
            tx.send(Record::note(format!("line {k}"))).await.unwrap();
            tokio::task::yield_now().await;
        }
        drop(tx);
        let report = logger.await.unwrap().unwrap();
        let i = Stream::Err as usize;
        assert_eq!(report.records, 0, "nothing reached the file");
        assert_eq!(
            dropped[i].load(Ordering::Relaxed),
            10,
            "every record counted"
        );
        assert!(io_errors[i].load(Ordering::Relaxed) >= 1);
    }
}
