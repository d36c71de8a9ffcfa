//! The periodic messages (status each second, attitude and position at `gcs.telemetry_hz`,
//! the takeoff point every 5 s), their rates as a ground station sets them, and a message
//! sent once on request.

use super::link::Link;
use super::state::{Gcs, Stream};
use crate::config::GcsConfig;
use crate::gcs::telemetry::{self as tm, Snapshot};
use mavlink::MessageData;
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

/// The messages the link can send, by id.
const KNOWN: [u32; 11] = [
    HEARTBEAT_DATA::ID,
    SYS_STATUS_DATA::ID,
    GPS_RAW_INT_DATA::ID,
    ATTITUDE_DATA::ID,
    LOCAL_POSITION_NED_DATA::ID,
    GLOBAL_POSITION_INT_DATA::ID,
    HOME_POSITION_DATA::ID,
    EXTENDED_SYS_STATE_DATA::ID,
    ESTIMATOR_STATUS_DATA::ID,
    AUTOPILOT_VERSION_DATA::ID,
    MISSION_CURRENT_DATA::ID,
];

/// Message `id` from the snapshot; none when it has nothing to say yet (no estimate, no fix,
/// no takeoff point).
fn build(id: u32, s: &Snapshot, system_id: u8) -> Option<MavMessage> {
    match id {
        HEARTBEAT_DATA::ID => Some(tm::heartbeat(s)),
        SYS_STATUS_DATA::ID => Some(tm::sys_status(s)),
        GPS_RAW_INT_DATA::ID => tm::gps_raw(s),
        ATTITUDE_DATA::ID => tm::attitude(s),
        LOCAL_POSITION_NED_DATA::ID => tm::local_position(s),
        GLOBAL_POSITION_INT_DATA::ID => tm::global_position(s),
        HOME_POSITION_DATA::ID => tm::home_position(s),
        EXTENDED_SYS_STATE_DATA::ID => Some(tm::extended_sys_state(s)),
        ESTIMATOR_STATUS_DATA::ID => tm::estimator_status(s),
        AUTOPILOT_VERSION_DATA::ID => Some(tm::autopilot_version(system_id)),
        MISSION_CURRENT_DATA::ID => s.mission.as_ref().map(tm::mission_current),
        _ => None,
    }
}

pub(super) fn default_streams(cfg: &GcsConfig, now: Instant) -> Vec<Stream> {
    let fast = Duration::from_secs_f64(1.0 / cfg.telemetry_hz);
    let second = Duration::from_secs(1);
    [
        (HEARTBEAT_DATA::ID, second),
        (SYS_STATUS_DATA::ID, second),
        (EXTENDED_SYS_STATE_DATA::ID, second),
        (ESTIMATOR_STATUS_DATA::ID, second),
        (GPS_RAW_INT_DATA::ID, second),
        (HOME_POSITION_DATA::ID, 5 * second),
        (MISSION_CURRENT_DATA::ID, second),
        (ATTITUDE_DATA::ID, fast),
        (LOCAL_POSITION_NED_DATA::ID, fast),
        (GLOBAL_POSITION_INT_DATA::ID, fast),
    ]
    .into_iter()
    .map(|(id, every)| Stream {
        id,
        default: Some(every),
        interval: Some(every),
        next: now,
    })
    .collect()
}

impl Gcs {
    /// The periodic messages due at `now`.
    pub(super) fn send_due(&mut self, now: Instant, link: &mut Link) {
        let snap = self.snapshot();
        let system_id = self.ctx.cfg.system_id;
        let mut due = Vec::new();
        for s in &mut self.streams {
            let Some(every) = s.interval else { continue };
            if now < s.next {
                continue;
            }
            // Keep the rate without bunching after a late tick.
            s.next = (s.next + every).max(now);
            due.push(s.id);
        }
        for id in due {
            if let Some(m) = build(id, &snap, system_id) {
                self.send(&m, link);
            }
        }
    }

    /// REQUEST_MESSAGE: the message now, if it can be built.
    pub(super) fn send_by_id(&mut self, id: u32, link: &mut Link) -> MavResult {
        if !KNOWN.contains(&id) {
            return MavResult::MAV_RESULT_DENIED;
        }
        match build(id, &self.snapshot(), self.ctx.cfg.system_id) {
            Some(m) => {
                self.send(&m, link);
                MavResult::MAV_RESULT_ACCEPTED
            }
            None => MavResult::MAV_RESULT_FAILED,
        }
    }

    /// SET_MESSAGE_INTERVAL: negative stops the message, 0 restores its default rate;
    /// faster than the tick is the tick.
    pub(super) fn set_interval(&mut self, id: u32, interval_us: f32) -> MavResult {
        let Some(s) = self.streams.iter_mut().find(|s| s.id == id) else {
            return MavResult::MAV_RESULT_DENIED;
        };
        s.interval = if interval_us < 0.0 {
            None
        } else if interval_us == 0.0 {
            s.default
        } else {
            Some(Duration::from_micros(interval_us as u64).max(super::TICK))
        };
        s.next = Instant::now();
        MavResult::MAV_RESULT_ACCEPTED
    }
}
