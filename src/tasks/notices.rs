//! Notices: what the flight tells the ground-station link beside the logs — the commander's
//! events (mode changes, failsafes, refusals) and what became of each command. A bounded
//! queue the control path only ever `try_send`s into (no lock a reader holds can stall it);
//! what a full queue cannot take is dropped and counted.

pub use crate::gcs::connection::Notice;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::sync::mpsc;

/// Notices held for the link: a burst of refusals from a flood of commands fits.
const QUEUE: usize = 256;

/// The sending side; cheap to clone. `Notices::default()` sends nowhere.
#[derive(Debug, Clone, Default)]
pub struct Notices {
    tx: Option<mpsc::Sender<Notice>>,
    dropped: Arc<AtomicU64>,
}

impl Notices {
    /// A queue and its one reader (the link).
    pub fn channel() -> (Self, mpsc::Receiver<Notice>) {
        let (tx, rx) = mpsc::channel(QUEUE);
        let notices = Notices {
            tx: Some(tx),
            dropped: Arc::default(),
        };
        (notices, rx)
    }

    /// Never waits: a full queue drops the notice (counted), a closed one ignores it.
    pub fn send(&self, n: Notice) {
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
}
