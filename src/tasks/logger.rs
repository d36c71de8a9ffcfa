//! Loggers: one task per stream, writing `<run>/<stream>.log` in the original's formats.
//!
//! In: records through a bounded channel per stream; producers use `try_send` only, so a slow
//! disk never slows the control path: what cannot be queued is dropped and counted.
//! Out: the stream's file, written in batches and flushed when the stream closes.
//! Ends: when every sender is gone and the queue is drained.

use crate::logs::{self, ImuRawRecord, KalmanInRecord};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

/// The streams, in index order.
pub const STREAMS: [&str; 7] = ["imu_raw", "kalman_in", "x_hat", "w", "int", "gps", "err"];

/// One record of one stream.
#[derive(Debug, Clone)]
pub enum Record {
    ImuRaw(ImuRawRecord),
    KalmanIn(KalmanInRecord),
    XHat([f64; 15]),
    /// Command time and the speeds sent.
    W(i64, [f64; 4]),
    /// Control time, integrators, how many are meaningful.
    Int(i64, [f64; 4], usize),
    /// Time of a fake GPS sample (the original's time-only gps.log line).
    Gps(i64),
    /// A gpsd fix fused by the filter, logged with the time before which it arrived.
    GpsFix(i64, crate::tasks::gps_client::LiveFix),
    /// The header of a gps.log holding gpsd fixes.
    GpsHeader,
    /// A line of free text (err.log).
    Err(String),
}

impl Record {
    /// Index of the record's stream in [`STREAMS`].
    pub fn stream(&self) -> usize {
        match self {
            Record::ImuRaw(_) => 0,
            Record::KalmanIn(_) => 1,
            Record::XHat(_) => 2,
            Record::W(..) => 3,
            Record::Int(..) => 4,
            Record::Gps(_) | Record::GpsFix(..) | Record::GpsHeader => 5,
            Record::Err(_) => 6,
        }
    }

    /// Appends the record in its stream's format.
    pub fn write(&self, out: &mut String) {
        match self {
            Record::ImuRaw(r) => r.write(out),
            Record::KalmanIn(r) => r.write(out),
            Record::XHat(x) => logs::write_values_row(out, None, x),
            Record::W(t, w) => logs::write_values_row(out, Some(*t), w),
            Record::Int(t, x, n) => logs::write_values_row(out, Some(*t), &x[..*n]),
            Record::Gps(t) => {
                out.push_str(&logs::fmt_time_us(*t));
                out.push_str("\t\n");
            }
            Record::GpsFix(t, l) => logs::write_gps_fix(
                out,
                *t,
                l.stamp_us,
                l.fix.mode,
                l.sample.pos_m,
                l.fix.lat_deg,
                l.fix.lon_deg,
            ),
            Record::GpsHeader => {
                out.push_str(logs::UQUAD_GPS_HEADER);
                out.push('\n');
            }
            Record::Err(s) => {
                out.push_str(s);
                out.push('\n');
            }
        }
    }
}

/// A logger that stops writing for a while once it has written some records (fault injection
/// for tests and the simulator: a stalled disk).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogStall {
    /// Index in [`STREAMS`].
    pub stream: usize,
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
        let i = rec.stream();
        if let Some(tx) = self.senders.get(i)
            && tx.try_send(rec).is_err()
        {
            self.dropped[i].fetch_add(1, Ordering::Relaxed);
        }
    }

    pub fn err(&self, line: impl Into<String>) {
        self.log(Record::Err(line.into()));
    }

    /// Dropped records per stream, in [`STREAMS`] order.
    pub fn dropped(&self) -> [u64; 7] {
        std::array::from_fn(|i| self.dropped[i].load(Ordering::Relaxed))
    }
}

/// What a logger wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggerReport {
    pub stream: &'static str,
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
    for (i, name) in STREAMS.iter().enumerate() {
        let path = dir.join(format!("{name}.log"));
        let file = tokio::fs::File::create(&path).await?;
        let (tx, rx) = mpsc::channel(capacity);
        senders.push(tx);
        let stall = stall.filter(|s| s.stream == i);
        handles.push(tokio::spawn(run(name, path, file, rx, stall)));
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
    stream: &'static str,
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
                stream,
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
