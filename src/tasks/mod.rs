//! Tasks of the flight runtime; each file's header says In / Out / rate / when it ends.

pub mod controller;
pub mod esc_writer;
pub mod estimator;
pub mod gcs;
pub mod gps_client;
pub mod heartbeats;
pub mod imu_reader;
pub mod latency;
pub mod logger;
pub mod notices;
pub mod prearm;
pub mod watchdog;

use crate::core::flight::{FlightRecord, Outputs};
use crate::core::watchdog::Event;
use crate::logs::Record;
use heartbeats::Heartbeats;
use logger::LogHub;
use std::sync::Arc;

/// Where the control path's tasks put the flight's records and watchdog events: the loggers
/// (never waited on: drops are counted) and the watchdog's inbox.
#[derive(Debug, Clone)]
pub struct TaskOutputs {
    pub logs: LogHub,
    pub beats: Arc<Heartbeats>,
    /// The commander's events, for the operators' links.
    pub notices: notices::Notices,
}

impl Outputs for TaskOutputs {
    fn record(&mut self, r: FlightRecord) {
        match &r {
            FlightRecord::Note(line) => tracing::info!("{line}"),
            FlightRecord::Commander(e) => self.notices.send(notices::Notice::Event(e.clone())),
            _ => {}
        }
        self.logs.log(Record::Flight(r));
    }

    fn watchdog(&mut self, e: Event) {
        self.beats.report(e);
    }
}

/// SCHED_FIFO priorities of the flight's threads (higher runs first): the watchdog above all,
/// so that nothing it watches can silence it; the ESC writer and the simulator's physics (the
/// edges) above the control path they serve.
pub const WATCHDOG_PRIORITY: i32 = 70;
pub const ESC_WRITER_PRIORITY: i32 = 60;
pub const SIM_PRIORITY: i32 = 60;
pub const CONTROL_PRIORITY: i32 = 50;

/// The message a panic carried (`panic!`'s text), for the run's error.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

/// Locks the process's memory, now and to come, so that no page fault stalls the control
/// path.
pub fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall takes flags only.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc != 0 {
        return Err(format!(
            "mlockall not permitted ({})",
            std::io::Error::last_os_error()
        ));
    }
    Ok(())
}

/// Whether the flight can run as it must: SCHED_FIFO at the watchdog's priority (tried on a
/// short-lived thread) and its memory locked. Why not, when it cannot.
pub fn realtime_permitted() -> Result<(), String> {
    let fifo = std::thread::spawn(|| set_fifo(WATCHDOG_PRIORITY))
        .join()
        .unwrap_or_else(|_| Err("the priority probe failed".to_string()));
    fifo.and_then(|()| lock_memory())
}

/// SCHED_FIFO at `priority` for the calling thread.
fn set_fifo(priority: i32) -> Result<(), String> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: sets the calling thread's scheduling policy; no memory is passed but `param`.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc != 0 {
        return Err(format!(
            "SCHED_FIFO at priority {priority} not permitted ({})",
            std::io::Error::last_os_error()
        ));
    }
    Ok(())
}

/// Starts a named OS thread running `f`, first raised to SCHED_FIFO `priority` when
/// `realtime` (a warning when not permitted).
pub fn spawn_thread<T: Send + 'static>(
    name: &'static str,
    realtime: bool,
    priority: i32,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::io::Result<std::thread::JoinHandle<T>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            if realtime {
                raise_priority(name, priority);
            }
            f()
        })
}

/// Asks for SCHED_FIFO at `priority` for the calling thread; warns when not permitted.
fn raise_priority(thread: &str, priority: i32) {
    if let Err(e) = set_fifo(priority) {
        tracing::warn!(thread, "{e}; running at normal priority");
    }
}
