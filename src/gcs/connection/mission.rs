//! The mission protocol's vehicle side. Upload: MISSION_COUNT, then each item asked for with
//! MISSION_REQUEST_INT (asked again after a second, given up after five tries); the whole
//! upload becomes a mission file (`crate::gcs::mission`), which the owner writes into the run
//! folder and plans off the control path ([`Effect::PlanMission`]); the plan goes to the
//! flight as an operator input, and MISSION_ACK follows the commander's verdict. Download
//! (MISSION_REQUEST_LIST) returns the last accepted upload. While a mission flies:
//! MISSION_CURRENT each second and at each change, MISSION_ITEM_REACHED for each item done.

use super::{Connection, Effect};
use crate::core::commander::OperatorInput;
use crate::core::mission::MissionPlan;
use crate::gcs::mission::{self as conv, Anchor, MAX_ITEMS};
use crate::gcs::telemetry::MissionStatus;
use mavlink::dialects::common::*;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// An item not come within this is asked for again; after `TRIES` asks the upload is
/// cancelled.
pub const ASK_AGAIN: Duration = Duration::from_secs(1);
pub const TRIES: u8 = 5;
/// An upload not planned and answered by the flight within this never will be (a worker that
/// failed, a flight that has ended).
pub const VERDICT_TIMEOUT: Duration = Duration::from_secs(10);

/// What planning an upload needs from the profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionSettings {
    /// `mission.speed_m_s`, until an item changes it.
    pub speed_m_s: f64,
    /// `control.hover_z_m`: where a mission without a takeoff starts from, m.
    pub hover_z_m: f64,
    /// The items of the mission loaded at start, if any.
    pub loaded_items: Option<usize>,
}

/// An upload under way.
struct Upload {
    partner: (u8, u8),
    count: u16,
    items: Vec<MISSION_ITEM_INT_DATA>,
    asked_at: Instant,
    tries: u8,
}

/// An upload being planned (by the owner) or judged (by the commander).
struct Judged {
    partner: (u8, u8),
    name: String,
    flown: Flown,
    /// When it was last moved on (its planning began, or its plan went to the flight).
    since: Instant,
}

/// The mission the commander has: its upload (empty for a mission file given at start) and
/// the upload's sequence number of each of the file's items.
#[derive(Default)]
struct Flown {
    items: Vec<MISSION_ITEM_INT_DATA>,
    seq_of_item: Vec<u16>,
}

/// The link's mission state.
pub(super) struct Missions {
    settings: Option<MissionSettings>,
    upload: Option<Upload>,
    judged: Option<Judged>,
    flown: Option<Flown>,
    uploads: u32,
    /// The last MISSION_CURRENT sent, and the last item reached (upload numbering).
    told: Option<MissionStatus>,
    reached: Option<u16>,
    /// Download requests for items there are not (each answered; told once in a hundred).
    missing_requests: u64,
}

impl Missions {
    pub(super) fn new(settings: Option<MissionSettings>) -> Self {
        let flown = settings.and_then(|s| s.loaded_items).map(|n| Flown {
            items: Vec::new(),
            seq_of_item: (0..n)
                .map(|i| u16::try_from(i).unwrap_or(u16::MAX))
                .collect(),
        });
        Missions {
            settings,
            upload: None,
            judged: None,
            flown,
            uploads: 0,
            told: None,
            reached: None,
            missing_requests: 0,
        }
    }

    /// The upload's sequence number of the file's item `item`.
    fn seq(&self, item: usize) -> Option<u16> {
        self.flown.as_ref()?.seq_of_item.get(item).copied()
    }

    /// When an item is asked for again, or a verdict given up on.
    pub(super) fn next_timer(&self) -> Option<Instant> {
        let ask = self.upload.as_ref().map(|u| u.asked_at + ASK_AGAIN);
        let verdict = self.judged.as_ref().map(|j| j.since + VERDICT_TIMEOUT);
        ask.into_iter().chain(verdict).min()
    }
}

/// The system and component a mission message is for.
#[allow(deprecated)]
pub(super) fn target(m: &MavMessage) -> Option<(u8, u8)> {
    Some(match m {
        MavMessage::MISSION_COUNT(c) => (c.target_system, c.target_component),
        MavMessage::MISSION_ITEM_INT(i) => (i.target_system, i.target_component),
        MavMessage::MISSION_ITEM(i) => (i.target_system, i.target_component),
        MavMessage::MISSION_REQUEST_LIST(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_REQUEST_INT(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_REQUEST(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_CLEAR_ALL(r) => (r.target_system, r.target_component),
        _ => return None,
    })
}

fn ack(to: (u8, u8), result: MavMissionResult) -> MavMessage {
    ack_of(to, result, MavMissionType::MAV_MISSION_TYPE_MISSION)
}

/// MISSION_ACK for a transaction of `mission_type` (a ground station drops an answer of
/// another type).
fn ack_of(to: (u8, u8), result: MavMissionResult, mission_type: MavMissionType) -> MavMessage {
    MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: to.0,
        target_component: to.1,
        mavtype: result,
        mission_type,
        opaque_id: 0,
    })
}

impl Connection {
    /// The mission protocol's messages addressed to this vehicle (older ground stations'
    /// superseded MISSION_ITEM and MISSION_REQUEST too).
    #[allow(deprecated)]
    pub(super) fn on_mission_message(&mut self, now: Instant, m: MavMessage, from: (u8, u8)) {
        let Some((system, component)) = target(&m) else {
            return;
        };
        if !self.for_us(system, component) {
            return;
        }
        match m {
            MavMessage::MISSION_COUNT(c) => self.on_mission_count(now, c, from),
            MavMessage::MISSION_ITEM_INT(i) => self.on_mission_item(now, i, from),
            MavMessage::MISSION_ITEM(i) => match conv::item_int(&i) {
                Ok(i) => self.on_mission_item(now, i, from),
                Err((result, why)) => self.on_bad_mission_item(from, result, &why),
            },
            MavMessage::MISSION_REQUEST_LIST(r) => self.on_mission_list(from, r.mission_type),
            MavMessage::MISSION_REQUEST_INT(r) => self.on_mission_request(r.seq, from),
            MavMessage::MISSION_REQUEST(r) => self.on_mission_request(r.seq, from),
            MavMessage::MISSION_CLEAR_ALL(r) => self.on_mission_clear(r.mission_type, from),
            _ => {}
        }
    }

    /// A refused upload (or request): acknowledged with `result`, told as STATUSTEXT and
    /// written to err.log.
    fn mission_refuse(&mut self, to: (u8, u8), result: MavMissionResult, why: &str) {
        self.send(&ack(to, result));
        self.text(MavSeverity::MAV_SEVERITY_WARNING, why);
        self.err_log(why);
    }

    /// A mission written by a sender that may not command: denied, addressed to it (no
    /// text: a stranger must not fill the ground station's screen).
    pub(super) fn mission_deny(&mut self, to: (u8, u8)) {
        self.send(&ack(to, MavMissionResult::MAV_MISSION_DENIED));
    }

    /// Why an upload of `count` items from `from` cannot begin, if it cannot.
    fn upload_refusal(&self, count: u16, from: (u8, u8)) -> Option<(MavMissionResult, String)> {
        use MavMissionResult::*;
        let m = &self.missions;
        let why = if m.upload.as_ref().is_some_and(|u| u.partner != from) {
            (
                MAV_MISSION_DENIED,
                "another ground station is uploading".into(),
            )
        } else if m.settings.is_none() {
            (MAV_MISSION_DENIED, "this run cannot plan missions".into())
        } else if m.judged.is_some() {
            (
                MAV_MISSION_DENIED,
                "the last one is still being planned".into(),
            )
        } else if count == 0 {
            let why = "no items (a mission cannot be cleared; upload another)";
            (MAV_MISSION_DENIED, why.into())
        } else if count > MAX_ITEMS {
            (
                MAV_MISSION_NO_SPACE,
                format!("{count} items, at most {MAX_ITEMS}"),
            )
        } else {
            return None;
        };
        Some((why.0, format!("mission upload: {}", why.1)))
    }

    /// MISSION_COUNT: an upload begins (a mission; an empty fence or rally list is taken).
    fn on_mission_count(&mut self, now: Instant, c: MISSION_COUNT_DATA, from: (u8, u8)) {
        use MavMissionResult::*;
        if c.mission_type != MavMissionType::MAV_MISSION_TYPE_MISSION {
            let result = if c.count == 0 {
                MAV_MISSION_ACCEPTED
            } else {
                let why = format!("mission upload: {:?} not supported", c.mission_type);
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &why);
                MAV_MISSION_UNSUPPORTED
            };
            return self.send(&ack_of(from, result, c.mission_type));
        }
        if let Some((result, why)) = self.upload_refusal(c.count, from) {
            return self.mission_refuse(from, result, &why);
        }
        self.missions.upload = Some(Upload {
            partner: from,
            count: c.count,
            items: Vec::with_capacity(usize::from(c.count)),
            asked_at: now,
            tries: 1,
        });
        self.ask(from, 0);
    }

    fn ask(&mut self, to: (u8, u8), seq: u16) {
        let msg = MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
            seq,
            target_system: to.0,
            target_component: to.1,
            mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
        });
        self.send(&msg);
    }

    /// MISSION_ITEM_INT (or MISSION_ITEM) of the upload: kept if it is the one asked for;
    /// the next is asked for, or the upload is planned.
    fn on_mission_item(&mut self, now: Instant, item: MISSION_ITEM_INT_DATA, from: (u8, u8)) {
        let Some(u) = self.missions.upload.as_mut() else {
            return;
        };
        let expected = u.items.len() as u16;
        if u.partner != from || item.seq != expected {
            // A repeat of an item already kept, or one ahead: ask for the expected again.
            if u.partner == from && item.seq > expected {
                self.ask(from, expected);
            }
            return;
        }
        u.items.push(item);
        u.asked_at = now;
        u.tries = 1;
        if u.items.len() < usize::from(u.count) {
            return self.ask(from, expected + 1);
        }
        if let Some(u) = self.missions.upload.take() {
            self.plan_upload(now, u);
        }
    }

    /// An item that cannot be read (a coordinate not a number): the upload under way from
    /// that partner ends, refused with the reason.
    fn on_bad_mission_item(&mut self, from: (u8, u8), result: MavMissionResult, why: &str) {
        if self
            .missions
            .upload
            .take_if(|u| u.partner == from)
            .is_some()
        {
            self.mission_refuse(from, result, why);
        }
    }

    /// A whole upload: as a mission file, for the owner to write and plan.
    fn plan_upload(&mut self, now: Instant, u: Upload) {
        let snap = self.snapshot(now);
        let Some(settings) = self.missions.settings else {
            return;
        };
        let estimate_m = snap.state.map(|x| [x[0], x[1], x[2]]);
        let anchor = Anchor::of(snap.fix.as_ref(), estimate_m, snap.home_m);
        let converted =
            match conv::convert(&u.items, &anchor, settings.speed_m_s, settings.hover_z_m) {
                Ok(c) => c,
                Err((result, why)) => return self.mission_refuse(u.partner, result, &why),
            };
        self.missions.uploads += 1;
        let name = format!("mission-{}.toml", self.missions.uploads);
        self.effects.push_back(Effect::PlanMission {
            name: name.clone(),
            text: converted.text,
        });
        self.missions.judged = Some(Judged {
            partner: u.partner,
            name,
            flown: Flown {
                items: u.items,
                seq_of_item: converted.seq_of_item,
            },
            since: now,
        });
    }

    /// The owner's plan of upload `name` (from [`Effect::PlanMission`]): to the flight, or
    /// refused with the loader's words.
    pub fn handle_plan(&mut self, now: Instant, name: &str, plan: Result<MissionPlan, String>) {
        self.tell_time(now);
        let Some(j) = self.missions.judged.as_mut().filter(|j| j.name == name) else {
            return;
        };
        match plan {
            Ok(plan) => {
                // The flight answers within a frame or two: its own 10 s from now.
                j.since = now;
                self.operator
                    .push_back(OperatorInput::Mission(Arc::new(plan)));
            }
            Err(why) => {
                let partner = j.partner;
                self.missions.judged = None;
                self.mission_refuse(partner, MavMissionResult::MAV_MISSION_DENIED, &why);
            }
        }
    }

    /// The flight's queue could not take the plan being judged: refused.
    pub(super) fn mission_not_taken(&mut self) {
        let Some(j) = self.missions.judged.take() else {
            return;
        };
        let why = format!("mission {}: the flight is not taking inputs now", j.name);
        self.mission_refuse(j.partner, MavMissionResult::MAV_MISSION_DENIED, &why);
    }

    /// The commander took the mission (it flies on `start`) or refused it (its text has
    /// gone out as the refusal's).
    pub(super) fn on_mission_verdict(&mut self, name: &str, refused: bool) {
        let Some(j) = self.missions.judged.take_if(|j| j.name == name) else {
            return;
        };
        if refused {
            self.send(&ack(j.partner, MavMissionResult::MAV_MISSION_DENIED));
            return;
        }
        self.send(&ack(j.partner, MavMissionResult::MAV_MISSION_ACCEPTED));
        self.missions.flown = Some(j.flown);
        self.missions.reached = None;
        self.missions.told = None;
    }

    /// Items asked for again, an upload given up, a verdict that will not come.
    pub(super) fn mission_timers(&mut self, now: Instant) {
        if let Some(u) = self.missions.upload.as_mut()
            && now.saturating_duration_since(u.asked_at) >= ASK_AGAIN
        {
            let (partner, seq) = (u.partner, u.items.len() as u16);
            if u.tries >= TRIES {
                self.missions.upload = None;
                let why = format!("mission upload: item {seq} did not come: cancelled");
                let cancelled = MavMissionResult::MAV_MISSION_OPERATION_CANCELLED;
                return self.mission_refuse(partner, cancelled, &why);
            }
            u.tries += 1;
            u.asked_at = now;
            self.ask(partner, seq);
        }
        // A plan that never came (the owner's planning failed) or a verdict that never came
        // (the flight has ended): the upload fails, and the next one is taken.
        let late = |j: &mut Judged| now.saturating_duration_since(j.since) >= VERDICT_TIMEOUT;
        if let Some(j) = self.missions.judged.take_if(late) {
            let why = format!("mission {}: not planned or not answered in time", j.name);
            self.mission_refuse(j.partner, MavMissionResult::MAV_MISSION_ERROR, &why);
        }
    }

    /// MISSION_CLEAR_ALL: fence and rally lists are not kept (nothing to clear); the mission
    /// is not cleared (upload another).
    fn on_mission_clear(&mut self, mission_type: MavMissionType, from: (u8, u8)) {
        use MavMissionResult::*;
        let kept_nothing = matches!(
            mission_type,
            MavMissionType::MAV_MISSION_TYPE_FENCE | MavMissionType::MAV_MISSION_TYPE_RALLY
        );
        if kept_nothing {
            self.send(&ack_of(from, MAV_MISSION_ACCEPTED, mission_type));
        } else {
            let why = "mission clear: not supported (upload another mission)";
            self.send(&ack_of(from, MAV_MISSION_DENIED, mission_type));
            self.text(MavSeverity::MAV_SEVERITY_WARNING, why);
            self.err_log(why);
        }
    }

    /// MISSION_REQUEST_LIST: the count of the last accepted upload.
    fn on_mission_list(&mut self, to: (u8, u8), mission_type: MavMissionType) {
        let count = match mission_type {
            MavMissionType::MAV_MISSION_TYPE_MISSION => self
                .missions
                .flown
                .as_ref()
                .map_or(0, |f| f.items.len() as u16),
            _ => 0,
        };
        let msg = MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
            count,
            target_system: to.0,
            target_component: to.1,
            mission_type,
            opaque_id: 0,
        });
        self.send(&msg);
    }

    /// MISSION_REQUEST_INT (or MISSION_REQUEST) of a download: the item as uploaded.
    fn on_mission_request(&mut self, seq: u16, to: (u8, u8)) {
        let item = self
            .missions
            .flown
            .as_ref()
            .and_then(|f| f.items.get(usize::from(seq)));
        let Some(item) = item else {
            // Every request is answered, but told (a text, err.log) once in a hundred: a
            // client asking for items there are not in a loop must not flood either.
            self.missions.missing_requests += 1;
            let n = self.missions.missing_requests;
            let result = MavMissionResult::MAV_MISSION_INVALID_SEQUENCE;
            if n % 100 != 1 {
                return self.send(&ack(to, result));
            }
            let why = format!("mission download: no item {seq} ({n} such requests so far)");
            return self.mission_refuse(to, result, &why);
        };
        let msg = MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
            target_system: to.0,
            target_component: to.1,
            current: u8::from(seq == 0),
            ..*item
        });
        self.send(&msg);
    }

    /// The commander finished the file's item `item`.
    pub(super) fn on_item_reached(&mut self, now: Instant, item: usize) {
        let Some(seq) = self.missions.seq(item) else {
            return;
        };
        // An upload item made of several of the file's (a waypoint and its hold) is reached
        // with its last.
        if self.missions.seq(item + 1) == Some(seq) {
            return;
        }
        self.missions.reached = Some(seq);
        self.send(&MavMessage::MISSION_ITEM_REACHED(
            MISSION_ITEM_REACHED_DATA { seq },
        ));
        self.send_mission_current(now);
    }

    /// Where the mission is: the item flown (or paused at), done, or not begun.
    pub(super) fn mission_status(
        &self,
        item: Option<usize>,
        flying: bool,
    ) -> Option<MissionStatus> {
        let m = &self.missions;
        let f = m.flown.as_ref()?;
        // The upload's items (a file's when it came from a file), and the last flown one.
        let total = if f.items.is_empty() {
            f.seq_of_item.len()
        } else {
            f.items.len()
        };
        let last = f.seq_of_item.last().copied();
        let (seq, state) = match (item.and_then(|i| m.seq(i)), m.reached) {
            (Some(s), _) if flying => (s, MissionState::MISSION_STATE_ACTIVE),
            (Some(s), _) => (s, MissionState::MISSION_STATE_PAUSED),
            (None, Some(r)) if Some(r) == last => (r, MissionState::MISSION_STATE_COMPLETE),
            // Not flown, or left (a hold, a landing, a return): `start` flies it from the
            // beginning.
            (None, _) => (0, MissionState::MISSION_STATE_NOT_STARTED),
        };
        let total = u16::try_from(total).unwrap_or(u16::MAX);
        Some(MissionStatus { seq, total, state })
    }

    /// MISSION_CURRENT now (each second, and when it changes).
    fn send_mission_current(&mut self, now: Instant) {
        if let Some(m) = self.snapshot(now).mission {
            self.missions.told = Some(m);
            self.send(&crate::gcs::telemetry::mission_current(&m));
        }
    }

    /// MISSION_CURRENT at once when the item or state changed since it was last sent.
    pub(super) fn mission_changed(&mut self, now: Instant) {
        let current = self.snapshot(now).mission;
        if current.is_some() && current != self.missions.told {
            self.send_mission_current(now);
        }
    }
}
