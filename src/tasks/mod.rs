//! Tasks of the flight runtime; each file's header says In / Out / rate / when it ends.

pub mod controller;
pub mod esc_writer;
pub mod estimator;
pub mod gps_client;
pub mod heartbeats;
pub mod imu_reader;
pub mod logger;
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
}

impl Outputs for TaskOutputs {
    fn record(&mut self, r: FlightRecord) {
        if let FlightRecord::Note(line) = &r {
            tracing::info!("{line}");
        }
        self.logs.log(Record::Flight(r));
    }

    fn watchdog(&mut self, e: Event) {
        self.beats.report(e);
    }
}

/// Asks for SCHED_FIFO at `priority` for the calling thread; warns when not permitted.
pub fn raise_priority(thread: &str, priority: i32) {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: sets the calling thread's scheduling policy; no memory is passed but `param`.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc != 0 {
        tracing::warn!(
            thread,
            "SCHED_FIFO not permitted ({}); running at normal priority",
            std::io::Error::last_os_error()
        );
    }
}
