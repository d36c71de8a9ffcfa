//! Notices: what the flight tells its operators' links beside the logs — the commander's
//! events (mode changes, failsafes, refusals) and what became of each command. A broadcast:
//! the control path never waits on it, and a link that falls behind misses the oldest and
//! is told how many.

use crate::core::commander::{Command, Event, LinkSource};
use tokio::sync::broadcast;

/// Notices held for the slowest link.
const QUEUE: usize = 256;

#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    Event(Event),
    /// A command as the commander took it: refused (and why) or done.
    Outcome {
        command: Command,
        source: LinkSource,
        refused: Option<String>,
    },
}

/// The sending side; cheap to clone. `Notices::default()` sends nowhere.
#[derive(Debug, Clone, Default)]
pub struct Notices(Option<broadcast::Sender<Notice>>);

impl Notices {
    pub fn new() -> Self {
        Notices(Some(broadcast::channel(QUEUE).0))
    }

    /// Never waits; without a listener the notice is dropped.
    pub fn send(&self, n: Notice) {
        if let Some(tx) = &self.0
            && tx.receiver_count() > 0
        {
            let _ = tx.send(n);
        }
    }

    /// A listener that sees every notice from now on.
    pub fn subscribe(&self) -> Option<broadcast::Receiver<Notice>> {
        self.0.as_ref().map(broadcast::Sender::subscribe)
    }
}
