//! The watchdog's inbox and the run's clock: the tasks and threads that feed the watchdog
//! report [`Event`]s here (a short lock, never a wait), and every stamp is µs since the run's
//! start.

pub use crate::core::watchdog::Event;
use std::sync::Mutex;
use std::time::Instant;

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
    pub fn take_into(&self, batch: &mut Vec<Event>) {
        batch.clear();
        if let Ok(mut v) = self.events.lock() {
            std::mem::swap(&mut *v, batch);
        }
    }
}
