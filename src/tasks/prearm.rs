//! The pre-arm facts a `fly` run observes for the commander, gathered so that the control
//! path never waits for them: the log folder is probed once a second on the main runtime;
//! the ESC writer publishes which ESCs answer its probe; the newest GPS fix and the control
//! thread's scheduling policy are read where they are.

use crate::core::commander::ArmFacts;
use crate::core::gps::LiveFix;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Duration;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

/// What the estimator task needs to build [`ArmFacts`].
#[derive(Debug, Clone)]
pub struct PreArm {
    /// Why the run folder cannot be written, as last probed.
    pub log_problem: watch::Receiver<Option<String>>,
    /// SCHED_FIFO is not required (`--allow-no-rt`, the simulator).
    pub realtime_waived: bool,
    pub gps_required: bool,
    pub gps_max_eph_m: f64,
    /// A fix older than this does not count, µs.
    pub gps_timeout_us: i64,
    pub addresses: [u8; 4],
    /// Where the verdict an `arm` would get now is published (the estimator task checks
    /// once a second), for SYS_STATUS's pre-arm bit.
    pub verdict: Arc<PrearmVerdict>,
}

/// Whether the pre-arm checks pass now, as last checked: none before the first check.
#[derive(Debug, Default)]
pub struct PrearmVerdict(AtomicU8);

impl PrearmVerdict {
    pub fn set(&self, pass: bool) {
        self.0.store(if pass { 1 } else { 2 }, Ordering::Relaxed);
    }

    pub fn get(&self) -> Option<bool> {
        match self.0.load(Ordering::Relaxed) {
            1 => Some(true),
            2 => Some(false),
            _ => None,
        }
    }
}

impl PreArm {
    /// The facts at `now_us`, on the control thread.
    pub fn facts(&self, esc_silent: Vec<u8>, fix: Option<&LiveFix>, now_us: i64) -> ArmFacts {
        let fresh = fix.filter(|f| now_us - f.stamp_us <= self.gps_timeout_us);
        ArmFacts {
            imu_stable: false,
            gps_required: self.gps_required,
            gps_eph_m: fresh.and_then(|f| f.fix.eph_m),
            gps_max_eph_m: self.gps_max_eph_m,
            log_error: self.log_problem.borrow().clone(),
            realtime: self.realtime_waived || holds_fifo(),
            esc_silent,
            // The flight sequence's own, like the IMU's settling.
            estimator: None,
        }
    }
}

/// The calling thread runs under SCHED_FIFO.
pub fn holds_fifo() -> bool {
    // SAFETY: sched_getscheduler(0) only reads the calling thread's policy.
    unsafe { libc::sched_getscheduler(0) == libc::SCHED_FIFO }
}

/// Probes the run folder once a second until `cancel` (on the main runtime, never on the
/// control path), publishing why it cannot be written, if it cannot.
pub async fn watch_log_dir(
    run_dir: PathBuf,
    tx: watch::Sender<Option<String>>,
    cancel: CancellationToken,
) {
    loop {
        let dir = run_dir.clone();
        let problem = tokio::task::spawn_blocking(move || log_dir_problem(&dir))
            .await
            .unwrap_or_else(|e| Some(format!("the log folder probe failed: {e}")));
        tx.send_replace(problem);
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tokio::time::sleep(Duration::from_secs(1)) => {}
        }
    }
}

/// The log folder check: a file can be created, written and removed in it. `Some(why)` when
/// it cannot (a full or read-only disk, a folder removed under the run).
pub fn log_dir_problem(run_dir: &std::path::Path) -> Option<String> {
    let probe = run_dir.join(".arm-check");
    let result = std::fs::write(&probe, b"uquad pre-arm check\n")
        .and_then(|()| std::fs::remove_file(&probe));
    result
        .err()
        .map(|e| format!("cannot write in {}: {e}", run_dir.display()))
}
