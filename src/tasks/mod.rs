//! Tasks of the flight runtime; each file's header says In / Out / rate / when it ends.

pub mod controller;
pub mod esc_writer;
pub mod estimator;
pub mod gcs;
pub mod gps_client;
pub mod heartbeats;
pub mod host_stall;
pub mod imu_reader;
pub mod latency;
pub mod logger;
pub mod notices;
pub mod prearm;
pub mod rc_reader;
pub mod status;
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

/// The CPU a flight thread runs on when the machine has two or more (and the run is
/// realtime). The ESC writer spins for the command it was told is coming: it must never share a
/// CPU with the control path that computes that command, or it would hold it off for the whole
/// spin. So the writer (and the watchdog, which wakes briefly every millisecond) take the last
/// CPU, the control path (and the simulator's physics, which preempts it only briefly) the first.
/// Everything else (the loggers, the operators' tasks, other programs) is left to the kernel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cpu {
    First,
    Last,
}

/// Starts a named OS thread running `f`, first raised to SCHED_FIFO `priority` and pinned to
/// its `cpu` when `realtime` (a warning when not permitted).
pub fn spawn_thread<T: Send + 'static>(
    name: &'static str,
    realtime: bool,
    priority: i32,
    cpu: Cpu,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::io::Result<std::thread::JoinHandle<T>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            if realtime {
                raise_priority(name, priority);
                match pin(cpu) {
                    Ok(pinned) => PINNED.set(pinned),
                    Err(e) => tracing::warn!(thread = name, "{e}; left where the kernel puts it"),
                }
            }
            f()
        })
}

thread_local! {
    static PINNED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether the calling flight thread was placed on its CPU (see [`Cpu`]): a realtime run on a
/// machine with two CPUs or more, and the kernel agreed.
pub fn pinned() -> bool {
    PINNED.get()
}

/// Pins the calling thread to the first or last CPU it is allowed on (true); nothing with fewer
/// than two (false).
fn pin(cpu: Cpu) -> Result<bool, String> {
    let size = std::mem::size_of::<libc::cpu_set_t>();
    // SAFETY: cpu_set_t is a plain bit array; all zeros is the empty set.
    let mut allowed: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: `allowed` is a cpu_set_t of `size` bytes, written by the call.
    if unsafe { libc::sched_getaffinity(0, size, &mut allowed) } != 0 {
        return Err(format!(
            "cannot read the CPUs allowed ({})",
            std::io::Error::last_os_error()
        ));
    }
    let cpus: Vec<usize> = (0..libc::CPU_SETSIZE as usize)
        // SAFETY: CPU_ISSET reads bit `c` < CPU_SETSIZE of `allowed`.
        .filter(|&c| unsafe { libc::CPU_ISSET(c, &allowed) })
        .collect();
    let chosen = match (cpu, cpus.as_slice()) {
        (_, [] | [_]) => return Ok(false),
        (Cpu::First, [first, ..]) => *first,
        (Cpu::Last, [.., last]) => *last,
    };
    // SAFETY: as above; CPU_SET writes bit `chosen` < CPU_SETSIZE.
    let mut one: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    unsafe { libc::CPU_SET(chosen, &mut one) };
    // SAFETY: `one` is a cpu_set_t of `size` bytes.
    if unsafe { libc::sched_setaffinity(0, size, &one) } != 0 {
        return Err(format!(
            "cannot pin to CPU {chosen} ({})",
            std::io::Error::last_os_error()
        ));
    }
    Ok(true)
}

/// Asks for SCHED_FIFO at `priority` for the calling thread; warns when not permitted.
fn raise_priority(thread: &str, priority: i32) {
    if let Err(e) = set_fifo(priority) {
        tracing::warn!(thread, "{e}; running at normal priority");
    }
}
