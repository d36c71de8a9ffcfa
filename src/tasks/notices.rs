//! Notices: what the flight tells the ground-station link beside the logs — the commander's
//! events (mode changes, failsafes, refusals) and what became of each command. A bounded
//! queue the control path only ever `try_send`s into (no lock a reader holds can stall it);
//! what a full queue cannot take is dropped and counted. The commander's mode is also kept in
//! an atomic as each change passes, so a watcher reads the mode even when no control step
//! follows it (the ESCs' start-up ramp, the calibration after arming, a halt's kill) and even
//! when a full queue dropped its notice.

use crate::core::commander::{Event, Mode};
pub use crate::gcs::connection::Notice;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use tokio::sync::mpsc;

/// Notices held for the link: a burst of refusals from a flood of commands fits.
const QUEUE: usize = 256;

/// The sending side; cheap to clone. `Notices::default()` sends nowhere (the mode is still
/// kept).
#[derive(Debug, Clone, Default)]
pub struct Notices {
    tx: Option<mpsc::Sender<Notice>>,
    dropped: Arc<AtomicU64>,
    mode: ModeSource,
}

/// The commander's mode as its last change said (disarmed before any).
#[derive(Debug, Clone, Default)]
pub struct ModeSource(Arc<AtomicU8>);

impl ModeSource {
    pub fn get(&self) -> Mode {
        let i = usize::from(self.0.load(Ordering::Acquire));
        Mode::ALL.get(i).copied().unwrap_or(Mode::Disarmed)
    }

    fn set(&self, mode: Mode) {
        let i = Mode::ALL.iter().position(|m| *m == mode).unwrap_or(0);
        self.0.store(i as u8, Ordering::Release);
    }
}

impl Notices {
    /// A queue and its one reader (the link).
    pub fn channel() -> (Self, mpsc::Receiver<Notice>) {
        let (tx, rx) = mpsc::channel(QUEUE);
        let notices = Notices {
            tx: Some(tx),
            ..Notices::default()
        };
        (notices, rx)
    }

    /// Never waits: a full queue drops the notice (counted), a closed one ignores it. A mode
    /// change is kept first, so a reader woken by its notice reads the new mode.
    pub fn send(&self, n: Notice) {
        if let Notice::Event(Event::Mode { mode, .. }) = &n {
            self.mode.set(*mode);
        }
        if let Some(tx) = &self.tx
            && let Err(mpsc::error::TrySendError::Full(_)) = tx.try_send(n)
        {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Notices a full queue dropped.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Where the commander's mode is read.
    pub fn mode(&self) -> ModeSource {
        self.mode.clone()
    }
}
