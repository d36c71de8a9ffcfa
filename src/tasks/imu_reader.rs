//! IMU reader: the serial edge.
//!
//! In: the IMU byte stream (a serial port, a pty, or an in-memory pipe).
//! Out: frames stamped when their last byte was decoded (µs since the run's start) to the
//! estimator; decoder counters in [`ImuStats`].
//! Rate: as the IMU sends (100 Hz). Ends: at end of stream, on a read error, or on cancel.

use crate::core::imu::frame::{FrameDecoder, RawFrame};
use bytes::BytesMut;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use crate::tasks::heartbeats::{Event, Heartbeats};

/// A decoded frame and when its last byte arrived.
#[derive(Debug, Clone, Copy)]
pub struct StampedFrame {
    pub frame: RawFrame,
    /// µs since the run's start.
    pub stamp_us: i64,
    pub at: Instant,
}

/// Counters of the serial edge.
#[derive(Debug, Default)]
pub struct ImuStats {
    pub frames: AtomicU64,
    pub discarded_bytes: AtomicU64,
    pub rejected_frames: AtomicU64,
    /// Frames the estimator could not take (it fell a whole queue behind).
    pub dropped_frames: AtomicU64,
}

/// Byte sent to put the IMU in binary mode with every sensor on (spec 1.1).
pub const BINARY_MODE_COMMAND: u8 = b'!';

pub async fn run<IO: AsyncRead + AsyncWrite + Unpin>(
    mut io: IO,
    beats: Arc<Heartbeats>,
    tx: mpsc::Sender<StampedFrame>,
    stats: Arc<ImuStats>,
    cancel: CancellationToken,
) -> std::io::Result<()> {
    io.write_all(&[BINARY_MODE_COMMAND]).await?;
    io.flush().await?;
    let mut decoder = FrameDecoder::new();
    let mut buf = BytesMut::with_capacity(4096);
    let mut last_stamp_us = i64::MIN;
    loop {
        let n = tokio::select! {
            _ = cancel.cancelled() => return Ok(()),
            r = io.read_buf(&mut buf) => r?,
        };
        if n == 0 {
            tracing::warn!("IMU stream ended");
            return Ok(());
        }
        let at = Instant::now();
        let read_us = beats.us(at);
        while let Some(frame) = decoder.next_frame(&mut buf) {
            // Strictly increasing stamps, even for frames decoded from one read: the logs'
            // "applied by the first step later than t" rules (GPS samples) then pick the same
            // step in a replay as in flight.
            let stamp_us = read_us.max(last_stamp_us + 1);
            last_stamp_us = stamp_us;
            stats.frames.fetch_add(1, Ordering::Relaxed);
            beats.report(Event::Frame(stamp_us));
            if tx
                .try_send(StampedFrame {
                    frame,
                    stamp_us,
                    at,
                })
                .is_err()
            {
                stats.dropped_frames.fetch_add(1, Ordering::Relaxed);
            }
        }
        let s = decoder.stats();
        stats
            .discarded_bytes
            .store(s.discarded_bytes, Ordering::Relaxed);
        stats
            .rejected_frames
            .store(s.rejected_frames, Ordering::Relaxed);
    }
}
