//! Watchdog: applies the pure policy of `core::watchdog` to what the other tasks report, and
//! halts the motors through the ESC writer's halt path (zero, then disable).
//!
//! In: events from the IMU reader (frame arrivals), the estimator (sanity inputs) and the ESC
//! writer (commands written, failed write cycles) through [`Heartbeats`].
//! Out: a halt request to the ESC writer; the trip, its times and the deadline misses in
//! [`WatchdogStatus`]; the run's cancellation after a halt.
//! Rate: checks every 500 µs on its own OS thread, so a stalled runtime cannot silence it.
//! Ends: after a halt, or when the run ends.

use crate::core::watchdog::Halt;
use crate::core::watchdog::{Event, Trip, Watchdog, WatchdogParams};
use crate::tasks::esc_writer::{EscMailbox, EscStatus};
use crate::tasks::heartbeats::Heartbeats;
use crate::tasks::host_stall::StallWatch;
use crate::tasks::{Cpu, WATCHDOG_PRIORITY};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

#[derive(Debug, Default)]
pub struct WatchdogStatus {
    pub deadline_misses: AtomicU64,
    /// When the watchdog last checked, µs since start: its own heartbeat.
    pub last_check_us: std::sync::atomic::AtomicI64,
    /// Gaps between two checks more than 5 ms late (`tasks::host_stall`): the host stalled
    /// the watchdog's thread (the flight's highest priority), and every thread with it.
    pub host_stalls: AtomicU64,
    /// The longest gap between two checks, µs.
    pub longest_gap_us: AtomicU64,
    pub halt: Mutex<Option<Halt>>,
    stop: AtomicBool,
}

impl WatchdogStatus {
    pub fn halt(&self) -> Option<Halt> {
        self.halt.lock().ok().and_then(|h| *h)
    }

    /// Ends the watchdog thread (the run is over).
    pub fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

const TICK: Duration = Duration::from_micros(500);

/// The way to the motors: the ESC writer's inbox and status, the ESCs' addresses, and how
/// long the writer may retry a stop.
pub struct HaltPath {
    pub mailbox: Arc<EscMailbox>,
    pub esc: Arc<EscStatus>,
    pub addresses: [u8; 4],
    pub retry: Duration,
}

/// Starts the watchdog thread.
pub fn spawn(
    params: WatchdogParams,
    beats: Arc<Heartbeats>,
    status: Arc<WatchdogStatus>,
    path: HaltPath,
    on_halt: impl FnOnce(Halt) + Send + 'static,
    cancel: CancellationToken,
    realtime: bool,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    crate::tasks::spawn_thread(
        "watchdog",
        realtime,
        WATCHDOG_PRIORITY,
        Cpu::Last,
        move || {
            // Without its watchdog the flight must not go on.
            let _halt = crate::tasks::esc_writer::HaltOnPanic {
                mailbox: path.mailbox.clone(),
                cancel: cancel.clone(),
            };
            let mut wd = Watchdog::new(params);
            let mut batch = Vec::with_capacity(256);
            let mut gaps = StallWatch::default();
            while !status.stop.load(Ordering::SeqCst) && !cancel.is_cancelled() {
                std::thread::sleep(TICK);
                if let Some(trip) = check(&mut wd, &beats, &status, &mut gaps, &mut batch) {
                    let halt = halt_motors(trip, &path, &beats);
                    if let Ok(mut h) = status.halt.lock() {
                        *h = Some(halt);
                    }
                    on_halt(halt);
                    cancel.cancel();
                    return;
                }
            }
        },
    )
}

/// One check: the reported events through the policy's one dispatch, then the clock.
fn check(
    wd: &mut Watchdog,
    beats: &Heartbeats,
    status: &WatchdogStatus,
    own: &mut StallWatch,
    batch: &mut Vec<Event>,
) -> Option<Trip> {
    // The time first, then the events: every frame that arrived before `now` is in this
    // batch, so a preemption here cannot look like a silent IMU.
    let now_us = beats.us(Instant::now());
    let previous_us = status.last_check_us.swap(now_us, Ordering::Relaxed);
    // Before the events: a command held up by the same stall is judged without it.
    note_own_gap(own, wd, status, previous_us, now_us);
    beats.take_into(batch);
    let mut trip = None;
    for &e in batch.iter() {
        trip = trip.or(wd.on_event(e, now_us));
    }
    let trip = trip.or_else(|| wd.tick(now_us));
    status
        .deadline_misses
        .store(wd.deadline_misses(), Ordering::Relaxed);
    trip
}

/// The gap since the previous check: counted when the host stalled this thread, and an
/// excused stall left out of what the policy judges (`tasks::host_stall`). The reader was
/// stalled with it, so frames sent meanwhile are still in the port's buffer; they arrive
/// within the next checks.
fn note_own_gap(
    own: &mut StallWatch,
    wd: &mut Watchdog,
    status: &WatchdogStatus,
    previous_us: i64,
    now_us: i64,
) {
    let gap_us = now_us - previous_us;
    if previous_us <= 0 || gap_us <= 0 {
        return;
    }
    status
        .longest_gap_us
        .fetch_max(gap_us as u64, Ordering::Relaxed);
    let late_us = gap_us - TICK.as_micros() as i64;
    if StallWatch::is_stall(late_us) {
        status.host_stalls.fetch_add(1, Ordering::Relaxed);
    }
    if let Some((from_us, to_us)) = own.excused(late_us, now_us) {
        wd.on_unobserved(from_us, to_us);
    }
}

/// A writer that has not settled its stop this long after its retry time is taken as hung.
const WRITER_GRACE: Duration = Duration::from_millis(500);

/// Halts through the ESC writer (zero, then disable, retried until acknowledged) and waits
/// for the stop to settle. A writer that never answers leaves the stop unconfirmed by all.
fn halt_motors(trip: Trip, path: &HaltPath, beats: &Heartbeats) -> Halt {
    path.mailbox
        .halt(crate::core::esc::StopReason::Halt(trip.reason));
    let asked = Instant::now();
    loop {
        if let Some(o) = path.esc.stop_outcome() {
            return o.halt(trip);
        }
        if asked.elapsed() > path.retry + WRITER_GRACE {
            return Halt {
                trip,
                halt_us: beats.us(Instant::now()),
                unconfirmed: path.addresses.map(Some),
            };
        }
        std::thread::sleep(Duration::from_micros(100));
    }
}
