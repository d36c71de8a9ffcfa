//! Watchdog: applies the pure policy of `core::watchdog` to what the other tasks report, and
//! halts the motors through the ESC writer's halt path (zero, then disable).
//!
//! In: events from the IMU reader (frame arrivals), the estimator (sanity inputs) and the ESC
//! writer (commands written, failed write cycles) through [`Heartbeats`].
//! Out: a halt request to the ESC writer; the trip, its times and the deadline misses in
//! [`WatchdogStatus`]; the run's cancellation after a halt.
//! Rate: checks every 500 µs on its own OS thread, so a stalled runtime cannot silence it.
//! Ends: after a halt, or when the run ends.

use crate::core::watchdog::{Trip, Watchdog, WatchdogParams};
use crate::tasks::esc_writer::{EscMailbox, EscPhase, EscStatus};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

/// What the tasks report to the watchdog (times in µs since the run's start).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    Frame(i64),
    Command {
        frame_us: i64,
        written_us: i64,
    },
    Estimate {
        step_us: i64,
        temp_c: f64,
        psi_rad: f64,
        phi_rad: f64,
    },
    EscFailures {
        cycles: u32,
        first_us: i64,
    },
}

/// The shared inbox of the watchdog; producers never wait more than a short lock.
#[derive(Debug)]
pub struct Heartbeats {
    start: Instant,
    events: Mutex<Vec<Event>>,
}

impl Heartbeats {
    pub fn new(start: Instant) -> Self {
        Heartbeats {
            start,
            events: Mutex::new(Vec::with_capacity(256)),
        }
    }

    pub fn start(&self) -> Instant {
        self.start
    }

    /// µs since the run's start.
    pub fn us(&self, at: Instant) -> i64 {
        at.saturating_duration_since(self.start).as_micros() as i64
    }

    pub fn report(&self, e: Event) {
        if let Ok(mut v) = self.events.lock() {
            v.push(e);
        }
    }

    /// Swaps the queued events into `batch` (cleared first): both buffers keep their
    /// capacity, so reporting an event allocates nothing once warmed up.
    fn take_into(&self, batch: &mut Vec<Event>) {
        batch.clear();
        if let Ok(mut v) = self.events.lock() {
            std::mem::swap(&mut *v, batch);
        }
    }
}

/// A halt as it happened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Halt {
    pub trip: Trip,
    /// When the ESCs were zeroed and disabled, µs since start.
    pub halt_us: i64,
}

impl Halt {
    /// From the triggering event to the halt, ms.
    pub fn latency_ms(&self) -> f64 {
        (self.halt_us - self.trip.event_us) as f64 / 1000.0
    }
}

#[derive(Debug, Default)]
pub struct WatchdogStatus {
    pub deadline_misses: AtomicU64,
    /// When the watchdog last checked, µs since start: its own heartbeat.
    pub last_check_us: std::sync::atomic::AtomicI64,
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

/// Starts the watchdog thread.
pub fn spawn(
    params: WatchdogParams,
    beats: Arc<Heartbeats>,
    status: Arc<WatchdogStatus>,
    (mailbox, esc): (Arc<EscMailbox>, Arc<EscStatus>),
    on_halt: impl FnOnce(Halt) + Send + 'static,
    cancel: CancellationToken,
    realtime: bool,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("watchdog".into())
        .spawn(move || {
            if realtime {
                crate::tasks::raise_priority("watchdog", 70);
            }
            let mut wd = Watchdog::new(params);
            let mut batch = Vec::with_capacity(256);
            loop {
                if status.stop.load(Ordering::SeqCst) || cancel.is_cancelled() {
                    return;
                }
                std::thread::sleep(TICK);
                // The time first, then the events: every frame that arrived before `now` is in
                // this batch, so a preemption here cannot look like a silent IMU.
                let now_us = beats.us(Instant::now());
                status.last_check_us.store(now_us, Ordering::Relaxed);
                let mut trip = None;
                beats.take_into(&mut batch);
                for &e in &batch {
                    let t = match e {
                        Event::Frame(at) => {
                            wd.on_frame(at);
                            None
                        }
                        Event::Command {
                            frame_us,
                            written_us,
                        } => wd.on_command(frame_us, written_us),
                        Event::Estimate {
                            step_us,
                            temp_c,
                            psi_rad,
                            phi_rad,
                        } => wd.on_estimate(step_us, temp_c, psi_rad, phi_rad),
                        Event::EscFailures { cycles, first_us } => {
                            wd.on_esc_failures(cycles, first_us, now_us.max(first_us))
                        }
                    };
                    trip = trip.or(t);
                }
                let trip = trip.or_else(|| wd.tick(now_us));
                status
                    .deadline_misses
                    .store(wd.deadline_misses(), Ordering::Relaxed);
                if let Some(trip) = trip {
                    mailbox.halt(trip.reason.name());
                    // The writer zeroes and disables at once; wait for it (bounded).
                    let asked = Instant::now();
                    while esc.phase() != EscPhase::Stopped
                        && asked.elapsed() < Duration::from_secs(1)
                    {
                        std::thread::sleep(Duration::from_micros(100));
                    }
                    let halt_us = esc
                        .stopped_at()
                        .map_or_else(|| beats.us(Instant::now()), |at| beats.us(at));
                    let halt = Halt { trip, halt_us };
                    if let Ok(mut h) = status.halt.lock() {
                        *h = Some(halt);
                    }
                    on_halt(halt);
                    cancel.cancel();
                    return;
                }
            }
        })
}
