//! gpsd client: positions from a real gpsd for the filter.
//!
//! In: gpsd's JSON reports over TCP (`gps.server`) after `?WATCH={"enable":true,"json":true}`.
//! Out: the newest fix, in the local frame (x north, y west, z up, origin at the first fix),
//! through a `watch` the estimator reads without waiting; counters in [`GpsStats`].
//! Rate: as gpsd reports (about 1 Hz). Ends: on cancel. When gpsd is unreachable or goes away
//! it reconnects with a capped, logged backoff while the filter goes on without GPS.

use crate::core::gps::{LiveFix, LocalFrame, Report, parse_report};
use futures_util::StreamExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio_util::codec::{FramedRead, LinesCodec};
use tokio_util::sync::CancellationToken;

/// The command that starts gpsd's JSON stream.
pub const WATCH_COMMAND: &[u8] = b"?WATCH={\"enable\":true,\"json\":true}\n";
/// Longest report line accepted (gpsd's are a few hundred bytes; SKY can be a few kB).
const MAX_LINE: usize = 64 * 1024;
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
const BACKOFF_START: Duration = Duration::from_millis(100);
const BACKOFF_CAP: Duration = Duration::from_secs(5);

#[derive(Debug, Default)]
pub struct GpsStats {
    pub connects: AtomicU64,
    pub disconnects: AtomicU64,
    pub reports: AtomicU64,
    pub fixes: AtomicU64,
    pub bad_lines: AtomicU64,
}

/// Why a gpsd session ended.
#[derive(Debug, thiserror::Error)]
pub enum GpsdError {
    #[error("cannot reach gpsd at {server}: {reason}")]
    Connect { server: String, reason: String },
    #[error("gpsd at {server} closed the connection")]
    Closed { server: String },
    #[error("reading from gpsd at {server}: {reason}")]
    Read { server: String, reason: String },
}

/// One connection to gpsd, already watching.
pub struct GpsdSession {
    server: String,
    lines: FramedRead<tokio::net::tcp::OwnedReadHalf, LinesCodec>,
    _write: tokio::net::tcp::OwnedWriteHalf,
}

impl GpsdSession {
    pub async fn connect(server: &str) -> Result<Self, GpsdError> {
        let err = |reason: String| GpsdError::Connect {
            server: server.to_string(),
            reason,
        };
        let stream = tokio::time::timeout(CONNECT_TIMEOUT, TcpStream::connect(server))
            .await
            .map_err(|_| err(format!("no answer within {CONNECT_TIMEOUT:?}")))?
            .map_err(|e| err(e.to_string()))?;
        let _ = stream.set_nodelay(true);
        let (read, mut write) = stream.into_split();
        write
            .write_all(WATCH_COMMAND)
            .await
            .map_err(|e| err(e.to_string()))?;
        Ok(GpsdSession {
            server: server.to_string(),
            lines: FramedRead::new(read, LinesCodec::new_with_max_length(MAX_LINE)),
            _write: write,
        })
    }

    /// The next report; a line that is not one is `Ok(None)` (counted by the caller).
    pub async fn next_report(&mut self) -> Result<Option<Report>, GpsdError> {
        match self.lines.next().await {
            None => Err(GpsdError::Closed {
                server: self.server.clone(),
            }),
            Some(Err(e)) => Err(GpsdError::Read {
                server: self.server.clone(),
                reason: e.to_string(),
            }),
            Some(Ok(line)) => Ok(parse_report(&line).ok()),
        }
    }
}

/// Keeps a gpsd session going and publishes every fix.
pub async fn run(
    server: String,
    start: Instant,
    tx: watch::Sender<Option<LiveFix>>,
    stats: Arc<GpsStats>,
    cancel: CancellationToken,
) {
    let mut frame = LocalFrame::default();
    let mut seq = 0u64;
    let mut backoff = BACKOFF_START;
    loop {
        let session = tokio::select! {
            _ = cancel.cancelled() => return,
            s = GpsdSession::connect(&server) => s,
        };
        match session {
            Ok(mut s) => {
                stats.connects.fetch_add(1, Ordering::Relaxed);
                tracing::info!(server, "connected to gpsd");
                backoff = BACKOFF_START;
                loop {
                    let r = tokio::select! {
                        _ = cancel.cancelled() => return,
                        r = s.next_report() => r,
                    };
                    match r {
                        Ok(Some(Report::Tpv(tpv))) => {
                            stats.reports.fetch_add(1, Ordering::Relaxed);
                            if let Some(fix) = tpv.fix() {
                                seq += 1;
                                stats.fixes.fetch_add(1, Ordering::Relaxed);
                                let mut sample =
                                    frame.to_local(fix.lat_deg, fix.lon_deg, fix.alt_m);
                                sample.vel_m_s = tpv.velocity_m_s();
                                tx.send_replace(Some(LiveFix {
                                    seq,
                                    fix,
                                    sample,
                                    stamp_us: start.elapsed().as_micros() as i64,
                                }));
                            }
                        }
                        Ok(Some(Report::Error { message })) => {
                            tracing::warn!(server, "gpsd error: {message}");
                        }
                        Ok(Some(_)) => {
                            stats.reports.fetch_add(1, Ordering::Relaxed);
                        }
                        Ok(None) => {
                            stats.bad_lines.fetch_add(1, Ordering::Relaxed);
                        }
                        Err(e) => {
                            stats.disconnects.fetch_add(1, Ordering::Relaxed);
                            tracing::warn!("{e}; reconnecting, the filter goes on without GPS");
                            break;
                        }
                    }
                }
            }
            Err(e) => {
                tracing::warn!("{e}; retrying in {} ms", backoff.as_millis());
            }
        }
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(BACKOFF_CAP);
    }
}
