//! The mission protocol's vehicle side. Upload: MISSION_COUNT, then each item asked for with
//! MISSION_REQUEST_INT (asked again after a second, given up after five tries); the whole
//! upload becomes a mission file in the run folder (`crate::gcs::mission`), which a blocking
//! worker loads and designs gains for, off this task and off the control path; the plan goes
//! to the flight as an operator input, and MISSION_ACK follows the commander's verdict.
//! Download (MISSION_REQUEST_LIST) returns the last accepted upload. While a mission flies:
//! MISSION_CURRENT each second and at each change, MISSION_ITEM_REACHED for each item done.

use super::link::Link;
use super::mission_state::{Designed, Flown, Judged, Upload};
use super::state::Gcs;
use crate::core::commander::OperatorInput;
use crate::gcs::mission::{self as conv, Anchor, MAX_ITEMS};
use crate::gcs::telemetry::MissionStatus;
use mavlink::dialects::common::*;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// An item not come within this is asked for again; after `TRIES` asks the upload is
/// cancelled.
const ASK_AGAIN: Duration = Duration::from_secs(1);
const TRIES: u8 = 5;
/// An upload not planned and answered by the flight within this never will be (a worker that
/// failed, a flight that has ended).
const VERDICT_TIMEOUT: Duration = Duration::from_secs(10);

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

impl Gcs {
    /// A refused upload (or request): acknowledged with `result`, told as STATUSTEXT and
    /// written to err.log.
    pub(super) fn mission_refuse(
        &mut self,
        to: (u8, u8),
        result: MavMissionResult,
        why: &str,
        link: &mut Link,
    ) {
        self.send(&ack(to, result), link);
        self.text(MavSeverity::MAV_SEVERITY_WARNING, why, link);
        self.ctx.store.logs.err(why);
    }

    /// A mission written by a sender that may not command: denied, addressed to it (no
    /// text: a stranger must not fill the ground station's screen).
    pub(super) fn mission_deny(&mut self, to: (u8, u8), link: &mut Link) {
        self.send(&ack(to, MavMissionResult::MAV_MISSION_DENIED), link);
    }

    /// MISSION_COUNT: an upload begins (a mission; an empty fence or rally list is taken).
    pub(super) fn on_mission_count(
        &mut self,
        c: MISSION_COUNT_DATA,
        from: (u8, u8),
        link: &mut Link,
    ) {
        use MavMissionResult::*;
        if c.mission_type != MavMissionType::MAV_MISSION_TYPE_MISSION {
            let result = if c.count == 0 {
                MAV_MISSION_ACCEPTED
            } else {
                let why = format!("mission upload: {:?} not supported", c.mission_type);
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &why, link);
                MAV_MISSION_UNSUPPORTED
            };
            return self.send(&ack_of(from, result, c.mission_type), link);
        }
        let other = self.missions.upload.as_ref().filter(|u| u.partner != from);
        let why = if other.is_some() {
            Some((
                MAV_MISSION_DENIED,
                "mission upload: another ground station is uploading".into(),
            ))
        } else if self.missions.desk.is_none() {
            Some((
                MAV_MISSION_DENIED,
                "mission upload: this run cannot plan missions".into(),
            ))
        } else if self.missions.judged.is_some() {
            Some((
                MAV_MISSION_DENIED,
                "mission upload: the last one is still being planned".into(),
            ))
        } else if c.count == 0 {
            Some((
                MAV_MISSION_DENIED,
                "mission upload: no items (a mission cannot be cleared; upload another)".into(),
            ))
        } else if c.count > MAX_ITEMS {
            Some((
                MAV_MISSION_NO_SPACE,
                format!("mission upload: {} items, at most {MAX_ITEMS}", c.count),
            ))
        } else {
            None
        };
        if let Some((result, why)) = why {
            return self.mission_refuse(from, result, &why, link);
        }
        self.missions.upload = Some(Upload {
            partner: from,
            count: c.count,
            items: Vec::with_capacity(usize::from(c.count)),
            asked_at: Instant::now(),
            tries: 1,
        });
        self.ask(from, 0, link);
    }

    fn ask(&mut self, to: (u8, u8), seq: u16, link: &mut Link) {
        let msg = MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
            seq,
            target_system: to.0,
            target_component: to.1,
            mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
        });
        self.send(&msg, link);
    }

    /// MISSION_ITEM_INT (or MISSION_ITEM) of the upload: kept if it is the one asked for;
    /// the next is asked for, or the upload is planned.
    pub(super) fn on_mission_item(
        &mut self,
        item: MISSION_ITEM_INT_DATA,
        from: (u8, u8),
        link: &mut Link,
    ) {
        let Some(u) = self.missions.upload.as_mut() else {
            return;
        };
        let expected = u.items.len() as u16;
        if u.partner != from || item.seq != expected {
            // A repeat of an item already kept, or one ahead: ask for the expected again.
            if u.partner == from && item.seq > expected {
                self.ask(from, expected, link);
            }
            return;
        }
        u.items.push(item);
        u.asked_at = Instant::now();
        u.tries = 1;
        if u.items.len() < usize::from(u.count) {
            return self.ask(from, expected + 1, link);
        }
        if let Some(u) = self.missions.upload.take() {
            self.plan_upload(u, link);
        }
    }

    /// An item that cannot be read (a coordinate not a number): the upload under way from
    /// that partner ends, refused with the reason.
    pub(super) fn on_bad_mission_item(
        &mut self,
        from: (u8, u8),
        result: MavMissionResult,
        why: &str,
        link: &mut Link,
    ) {
        if self
            .missions
            .upload
            .take_if(|u| u.partner == from)
            .is_some()
        {
            self.mission_refuse(from, result, why, link);
        }
    }

    /// A whole upload: as a mission file, planned by a blocking worker.
    fn plan_upload(&mut self, u: Upload, link: &mut Link) {
        let snap = self.snapshot();
        let Some(desk) = &self.missions.desk else {
            return;
        };
        let estimate_m = snap.state.map(|x| [x[0], x[1], x[2]]);
        let anchor = Anchor::of(snap.fix.as_ref(), estimate_m, snap.home_m);
        let c = &desk.profile.config;
        let converted = conv::convert(&u.items, &anchor, c.mission.speed_m_s, c.control.hover_z_m);
        let converted = match converted {
            Ok(c) => c,
            Err((result, why)) => return self.mission_refuse(u.partner, result, &why, link),
        };
        self.missions.uploads += 1;
        let name = format!("mission-{}.toml", self.missions.uploads);
        let (profile, path) = (desk.profile.clone(), desk.run_dir.join(&name));
        let (tx, text, worker_name) = (self.missions.done_tx.clone(), converted.text, name.clone());
        tokio::task::spawn_blocking(move || {
            let plan = std::fs::write(&path, &text)
                .map_err(|e| format!("mission upload: cannot write {}: {e}", path.display()))
                .and_then(|()| profile.plan_mission(&path, &text));
            let _ = tx.blocking_send(Designed {
                name: worker_name,
                plan,
            });
        });
        self.missions.judged = Some(Judged {
            partner: u.partner,
            name,
            flown: Flown {
                items: u.items,
                seq_of_item: converted.seq_of_item,
            },
            since: Instant::now(),
        });
    }

    /// A worker's plan: to the flight, or refused with the loader's words.
    pub fn on_designed(&mut self, d: Designed, link: &mut Link) {
        let Some(j) = self.missions.judged.as_mut().filter(|j| j.name == d.name) else {
            return;
        };
        let partner = j.partner;
        let refused = match d.plan {
            Ok(plan) => match self
                .ctx
                .operator
                .try_send(OperatorInput::Mission(Arc::new(plan)))
            {
                Ok(()) => {
                    // The flight answers within a frame or two: its own 10 s from now.
                    j.since = Instant::now();
                    return;
                }
                Err(_) => {
                    self.report.input_drops += 1;
                    format!("mission {}: the flight is not taking inputs now", d.name)
                }
            },
            Err(why) => why,
        };
        self.missions.judged = None;
        self.mission_refuse(
            partner,
            MavMissionResult::MAV_MISSION_DENIED,
            &refused,
            link,
        );
    }

    /// The commander took the mission (it flies on `start`) or refused it (its text has
    /// gone out as the refusal's).
    pub(super) fn on_mission_verdict(&mut self, name: &str, refused: bool, link: &mut Link) {
        let Some(j) = self.missions.judged.take_if(|j| j.name == name) else {
            return;
        };
        if refused {
            self.send(&ack(j.partner, MavMissionResult::MAV_MISSION_DENIED), link);
            return;
        }
        self.send(
            &ack(j.partner, MavMissionResult::MAV_MISSION_ACCEPTED),
            link,
        );
        self.missions.flown = Some(j.flown);
        self.missions.reached = None;
        self.missions.told = None;
    }

    /// Each tick: items asked for again, an upload given up, a verdict that will not come.
    pub(super) fn mission_timers(&mut self, now: Instant, link: &mut Link) {
        if let Some(u) = self.missions.upload.as_mut()
            && now.duration_since(u.asked_at) >= ASK_AGAIN
        {
            let (partner, seq) = (u.partner, u.items.len() as u16);
            if u.tries >= TRIES {
                self.missions.upload = None;
                let why = format!("mission upload: item {seq} did not come: cancelled");
                let cancelled = MavMissionResult::MAV_MISSION_OPERATION_CANCELLED;
                return self.mission_refuse(partner, cancelled, &why, link);
            }
            u.tries += 1;
            u.asked_at = now;
            self.ask(partner, seq, link);
        }
        // A plan that never came (a worker that failed) or a verdict that never came (the
        // flight has ended): the upload fails, and the next one is taken.
        let late = |j: &mut Judged| now.duration_since(j.since) >= VERDICT_TIMEOUT;
        if let Some(j) = self.missions.judged.take_if(late) {
            let why = format!("mission {}: not planned or not answered in time", j.name);
            self.mission_refuse(j.partner, MavMissionResult::MAV_MISSION_ERROR, &why, link);
        }
    }

    /// MISSION_CLEAR_ALL: fence and rally lists are not kept (nothing to clear); the mission
    /// is not cleared (upload another).
    pub(super) fn on_mission_clear(
        &mut self,
        mission_type: MavMissionType,
        from: (u8, u8),
        link: &mut Link,
    ) {
        use MavMissionResult::*;
        let kept_nothing = matches!(
            mission_type,
            MavMissionType::MAV_MISSION_TYPE_FENCE | MavMissionType::MAV_MISSION_TYPE_RALLY
        );
        if kept_nothing {
            self.send(&ack_of(from, MAV_MISSION_ACCEPTED, mission_type), link);
        } else {
            let why = "mission clear: not supported (upload another mission)";
            self.send(&ack_of(from, MAV_MISSION_DENIED, mission_type), link);
            self.text(MavSeverity::MAV_SEVERITY_WARNING, why, link);
            self.ctx.store.logs.err(why);
        }
    }

    /// MISSION_REQUEST_LIST: the count of the last accepted upload.
    pub(super) fn on_mission_list(
        &mut self,
        to: (u8, u8),
        mission_type: MavMissionType,
        link: &mut Link,
    ) {
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
        self.send(&msg, link);
    }

    /// MISSION_REQUEST_INT (or MISSION_REQUEST) of a download: the item as uploaded.
    pub(super) fn on_mission_request(&mut self, seq: u16, to: (u8, u8), link: &mut Link) {
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
                return self.send(&ack(to, result), link);
            }
            let why = format!("mission download: no item {seq} ({n} such requests so far)");
            return self.mission_refuse(to, result, &why, link);
        };
        let msg = MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
            target_system: to.0,
            target_component: to.1,
            current: u8::from(seq == 0),
            ..*item
        });
        self.send(&msg, link);
    }

    /// The commander finished the file's item `item`.
    pub(super) fn on_item_reached(&mut self, item: usize, link: &mut Link) {
        let Some(seq) = self.missions.seq(item) else {
            return;
        };
        // An upload item made of several of the file's (a waypoint and its hold) is reached
        // with its last.
        if self.missions.seq(item + 1) == Some(seq) {
            return;
        }
        self.missions.reached = Some(seq);
        self.send(
            &MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA { seq }),
            link,
        );
        self.send_mission_current(link);
    }

    /// Where the mission is: the item flown (or paused at), done, or not begun.
    pub(super) fn mission_status(
        &self,
        item: Option<usize>,
        flying: bool,
    ) -> Option<MissionStatus> {
        let f = self.missions.flown.as_ref()?;
        // The upload's items (a file's when it came from a file), and the last flown one.
        let total = if f.items.is_empty() {
            f.seq_of_item.len()
        } else {
            f.items.len()
        };
        let last = f.seq_of_item.last().copied();
        let (seq, state) = match (
            item.and_then(|i| self.missions.seq(i)),
            self.missions.reached,
        ) {
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
    pub(super) fn send_mission_current(&mut self, link: &mut Link) {
        let snap = self.snapshot();
        if let Some(m) = snap.mission {
            self.missions.told = Some(m);
            self.send(&crate::gcs::telemetry::mission_current(&m), link);
        }
    }

    /// MISSION_CURRENT at once when the item or state changed since it was last sent.
    pub(super) fn mission_changed(&mut self, link: &mut Link) {
        let now = self.snapshot().mission;
        if now.is_some() && now != self.missions.told {
            self.send_mission_current(link);
        }
    }
}
