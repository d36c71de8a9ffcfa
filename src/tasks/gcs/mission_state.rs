//! The mission protocol's state on the link (`mission` handles the messages): what an
//! upload needs (the profile, the run folder), an upload under way, one being planned or
//! judged, and the mission the commander has, with the upload's numbering of its items.

use crate::config::Profile;
use crate::core::mission::MissionPlan;
use crate::gcs::telemetry::MissionStatus;
use mavlink::dialects::common::MISSION_ITEM_INT_DATA;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::mpsc;

/// What the link needs to plan an upload: the profile (its checks, weights and speeds) and
/// the run folder the mission files go into; the mission loaded at start, if any.
pub struct MissionDesk {
    pub profile: Arc<Profile>,
    pub run_dir: PathBuf,
    pub loaded: Option<Arc<MissionPlan>>,
}

/// A worker's plan of upload file `name`.
pub struct Designed {
    pub(super) name: String,
    pub(super) plan: Result<MissionPlan, String>,
}

/// An upload under way.
pub(super) struct Upload {
    pub(super) partner: (u8, u8),
    pub(super) count: u16,
    pub(super) items: Vec<MISSION_ITEM_INT_DATA>,
    pub(super) asked_at: Instant,
    pub(super) tries: u8,
}

/// An upload being planned (by the worker) or judged (by the commander).
pub(super) struct Judged {
    pub(super) partner: (u8, u8),
    pub(super) name: String,
    pub(super) flown: Flown,
    /// When the upload was complete (its planning began).
    pub(super) since: Instant,
}

/// The mission the commander has: its upload (empty for a mission file given at start) and
/// the upload's sequence number of each of the file's items.
#[derive(Default)]
pub(super) struct Flown {
    pub(super) items: Vec<MISSION_ITEM_INT_DATA>,
    pub(super) seq_of_item: Vec<u16>,
}

/// The link's mission state.
pub struct Missions {
    pub(super) desk: Option<MissionDesk>,
    pub(super) upload: Option<Upload>,
    pub(super) judged: Option<Judged>,
    pub(super) flown: Option<Flown>,
    pub(super) uploads: u32,
    pub(super) done_tx: mpsc::Sender<Designed>,
    pub(super) done_rx: Option<mpsc::Receiver<Designed>>,
    /// The last MISSION_CURRENT sent, and the last item reached (upload numbering).
    pub(super) told: Option<MissionStatus>,
    pub(super) reached: Option<u16>,
    /// Download requests for items there are not (each answered; told once in a hundred).
    pub(super) missing_requests: u64,
}

impl Missions {
    pub fn new(desk: Option<MissionDesk>) -> Self {
        let (done_tx, done_rx) = mpsc::channel(1);
        let flown = desk
            .as_ref()
            .and_then(|d| d.loaded.as_ref())
            .map(|p| Flown {
                items: Vec::new(),
                seq_of_item: (0..p.mission.items.len()).map(|i| i as u16).collect(),
            });
        Missions {
            desk,
            upload: None,
            judged: None,
            flown,
            uploads: 0,
            done_tx,
            done_rx: Some(done_rx),
            missing_requests: 0,
            told: None,
            reached: None,
        }
    }

    /// The workers' plans, for the task's loop.
    pub fn take_designed(&mut self) -> mpsc::Receiver<Designed> {
        self.done_rx.take().unwrap_or_else(|| mpsc::channel(1).1)
    }

    /// The upload's sequence number of the file's item `item`.
    pub(super) fn seq(&self, item: usize) -> Option<u16> {
        self.flown.as_ref()?.seq_of_item.get(item).copied()
    }
}
