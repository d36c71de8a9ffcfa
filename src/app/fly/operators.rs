//! The operator's side of a `fly` run, all on the main runtime and never on the control path:
//! signals, the stdin keys, the console's statistics line, systemd's readiness and watchdog
//! pings.

use super::RunHandles;
use crate::core::control::ManualCommand;
use crate::tasks::esc_writer::EscMailbox;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// The console's statistics line: latency histogram, deadline misses, log drops, the current
/// estimate and motor speeds.
pub(super) fn console_stats(h: &RunHandles) -> String {
    // Latency histogram of the last second's commands (at most 100), in buckets of 100 µs.
    let mut hist = [0u32; 6];
    if let Ok(l) = h.esc_status.latencies_us.lock() {
        for &v in l.iter().rev().take(100) {
            hist[(v as usize / 100).min(5)] += 1;
        }
    }
    let mut s = format!(
        "stats t={:.1}s frames={} deadline_misses={} log_drops={} latency_us[<100,<200,<300,<400,<500,>=500]={:?}",
        h.beats.us(Instant::now()) as f64 / 1e6,
        h.imu_stats.frames.load(Ordering::Relaxed),
        h.wd_status.deadline_misses.load(Ordering::Relaxed),
        h.logs.dropped().total(),
        hist
    );
    if let Some(l) = *h.live.borrow() {
        let _ = std::fmt::Write::write_fmt(
            &mut s,
            format_args!(
                " step={} z={:.3} setpoint_z={:.2} roll={:+.3} pitch={:+.3} yaw={:+.3} w=[{:.1}, {:.1}, {:.1}, {:.1}]",
                l.step,
                l.x[2],
                l.setpoint_m[2],
                l.x[3],
                l.x[4],
                l.x[5],
                l.w_rad_s[0],
                l.w_rad_s[1],
                l.w_rad_s[2],
                l.w_rad_s[3]
            ),
        );
    }
    if let Some(halt) = h.wd_status.halt() {
        let _ =
            std::fmt::Write::write_fmt(&mut s, format_args!(" HALT={}", halt.trip.reason.name()));
    }
    s
}

/// READY=1 after the first IMU frame; WATCHDOG=1 every half `WatchdogSec` while the internal
/// watchdog checks and has not tripped; the pings stop for good at a trip.
pub(super) async fn notify_systemd(n: Arc<crate::hw::notify::Notifier>, h: RunHandles) {
    let poll = Duration::from_millis(10);
    while h.imu_stats.frames.load(Ordering::Relaxed) == 0 {
        tokio::select! {
            _ = h.cancel.cancelled() => return,
            _ = tokio::time::sleep(poll) => {}
        }
    }
    n.send("READY=1\nSTATUS=IMU frames arriving; flying");
    let Some(every) = crate::hw::notify::watchdog_interval() else {
        return;
    };
    loop {
        tokio::select! {
            _ = h.cancel.cancelled() => return,
            _ = tokio::time::sleep(every) => {}
        }
        if let Some(halt) = h.wd_status.halt() {
            n.send(&format!("STATUS=halted: {}", halt.trip.reason.name()));
            return;
        }
        let now_us = h.beats.us(Instant::now());
        let checked_us = h.wd_status.last_check_us.load(Ordering::Relaxed);
        // A watchdog that has not checked for 100 ms is not healthy either.
        if now_us - checked_us < 100_000 {
            n.send("WATCHDOG=1");
        }
    }
}

/// Reads the original's manual-mode keys (spec 5.2) from stdin, one byte at a time.
pub(super) async fn read_keys(tx: mpsc::Sender<ManualCommand>, cancel: CancellationToken) {
    use tokio::io::AsyncReadExt;
    let mut stdin = tokio::io::stdin();
    let mut byte = [0u8; 1];
    loop {
        let n = tokio::select! {
            _ = cancel.cancelled() => return,
            r = stdin.read(&mut byte) => match r {
                Ok(n) => n,
                Err(_) => return,
            },
        };
        if n == 0 {
            return;
        }
        if let Some(cmd) = ManualCommand::from_key(byte[0])
            && tx.send(cmd).await.is_err()
        {
            return;
        }
    }
}

/// SIGINT/SIGTERM: the first zeroes and disables the motors and ends the run; a second exits.
pub(super) async fn handle_signals(mailbox: Arc<EscMailbox>, cancel: CancellationToken) {
    use tokio::signal::unix::{SignalKind, signal};
    let (Ok(mut int), Ok(mut term)) = (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) else {
        tracing::error!("cannot install signal handlers");
        return;
    };
    for n in 0..2 {
        tokio::select! {
            _ = int.recv() => {}
            _ = term.recv() => {}
        }
        if n == 0 {
            tracing::info!("signal: stopping the motors and ending the run");
            mailbox.shutdown();
            cancel.cancel();
        } else {
            tracing::warn!("second signal: exiting now");
            std::process::exit(130);
        }
    }
}

/// Shuts the ESC writer down (zero, disable, end) when dropped; idempotent.
pub(super) struct StopEscOnDrop(pub(super) Arc<EscMailbox>);

impl Drop for StopEscOnDrop {
    fn drop(&mut self) {
        self.0.shutdown();
    }
}
