//! Tasks of the flight runtime; each file's header says In / Out / rate / when it ends.

pub mod controller;
pub mod esc_writer;
pub mod estimator;
pub mod gps_client;
pub mod imu_reader;
pub mod logger;
pub mod watchdog;

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
