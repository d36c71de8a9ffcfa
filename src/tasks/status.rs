//! Gathers the vehicle's status (`core::status`) from the run's shared state, in one place:
//! the ground-station link and the console's statistics line both read it here. Reading
//! never waits on the control path: watches are copied, counters are atomics. A paced
//! simulation, whose flight runs in one lock-step loop, publishes the whole status instead.

use crate::core::gps::LiveFix;
use crate::core::status::{Live, VehicleStatus};
use crate::tasks::esc_writer::EscStatus;
use crate::tasks::imu_reader::ImuStats;
use crate::tasks::notices::ModeSource;
use crate::tasks::watchdog::WatchdogStatus;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use tokio::sync::watch;

/// Where the status comes from.
#[derive(Clone)]
pub struct StatusSources {
    /// The commander's mode as its changes pass to the notices.
    pub mode: ModeSource,
    pub live: watch::Receiver<Option<Live>>,
    /// Live fixes (none: the profile flies without GPS).
    pub gps: Option<watch::Receiver<Option<LiveFix>>>,
    /// Why the run folder cannot be written, as last probed.
    pub log_problem: watch::Receiver<Option<String>>,
    pub watchdog: Arc<WatchdogStatus>,
    pub imu: Arc<ImuStats>,
    pub esc: Arc<EscStatus>,
    pub esc_addresses: [u8; 4],
    /// The control thread's CPU clock, where it can be read.
    pub control_cpu: Option<libc::clockid_t>,
    /// The pre-arm checks' verdict as the estimator task last checked it.
    pub prearm: Arc<crate::tasks::prearm::PrearmVerdict>,
    /// The RC receiver's reader (none: no receiver configured).
    pub rc: Option<Arc<crate::tasks::rc_reader::RcStats>>,
}

impl StatusSources {
    /// The status now.
    pub fn read(&self) -> VehicleStatus {
        VehicleStatus {
            mode: self.mode.get(),
            live: *self.live.borrow(),
            fix: self.gps.as_ref().and_then(|rx| *rx.borrow()),
            gps_used: self.gps.is_some(),
            imu_frames: self.imu.frames.load(Ordering::Relaxed),
            escs_answering: self.esc.silent_addresses(&self.esc_addresses).is_empty(),
            halt: self.watchdog.halt().map(|h| h.trip.reason),
            log_problem: self.log_problem.borrow().clone(),
            control_cpu_ns: self.control_cpu.map(crate::hw::cpu_clock::clock_ns),
            prearm_ok: self.prearm.get(),
            rc: self.rc.as_ref().and_then(|r| r.status()),
        }
    }
}

/// Where a watcher reads the vehicle's status: `fly`'s tasks' shared state, or the status a
/// lock-step loop publishes whole (`sim --mode paced`).
#[derive(Clone)]
pub enum StatusReader {
    Tasks(Box<StatusSources>),
    Published(watch::Receiver<VehicleStatus>),
}

impl StatusReader {
    /// The status now.
    pub fn read(&self) -> VehicleStatus {
        match self {
            StatusReader::Tasks(s) => s.read(),
            StatusReader::Published(rx) => rx.borrow().clone(),
        }
    }
}
