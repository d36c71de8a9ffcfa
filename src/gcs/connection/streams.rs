//! The periodic messages (status each second, attitude and position at `gcs.telemetry_hz`,
//! the takeoff point every 5 s), their rates as a ground station sets them, a message sent
//! once on request, and the vehicle's health as SYS_STATUS tells it (checked each second).

use super::{Connection, PACE};
use crate::config::GcsConfig;
use crate::gcs::telemetry::{self as tm, Health, Snapshot};
use mavlink::MessageData;
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

/// The messages the link can send on request (REQUEST_MESSAGE), by id.
pub const REQUESTABLE: [u32; 14] = [
    CURRENT_MODE_DATA::ID,
    AVAILABLE_MODES_DATA::ID,
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
    RC_CHANNELS_DATA::ID,
];

/// The health is checked this often.
const HEALTH_EVERY: Duration = Duration::from_secs(1);

/// A message sent every `interval`, or never (`None`).
struct Stream {
    id: u32,
    default: Option<Duration>,
    interval: Option<Duration>,
    next: Instant,
}

/// The periodic messages and the health they report.
pub(super) struct Streams {
    list: Vec<Stream>,
    pub(super) health: Health,
    health_at: Instant,
    frames_seen: u64,
    pub(super) load_permille: u16,
    control_cpu_ns: Option<u64>,
    /// A geofence breach was told (it stays told for the rest of the run).
    pub(super) fence_breached: bool,
    halt_told: bool,
}

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
        CURRENT_MODE_DATA::ID => Some(tm::current_mode(s)),
        RC_CHANNELS_DATA::ID => tm::rc_channels(s),
        _ => None,
    }
}

/// The periodic messages by id, with their default interval in seconds (0: every
/// 1/`gcs.telemetry_hz` s).
pub const PERIODIC_SENT: [(u32, f64); 12] = [
    (HEARTBEAT_DATA::ID, 1.0),
    (CURRENT_MODE_DATA::ID, 1.0),
    (SYS_STATUS_DATA::ID, 1.0),
    (EXTENDED_SYS_STATE_DATA::ID, 1.0),
    (ESTIMATOR_STATUS_DATA::ID, 1.0),
    (GPS_RAW_INT_DATA::ID, 1.0),
    (HOME_POSITION_DATA::ID, 5.0),
    (MISSION_CURRENT_DATA::ID, 1.0),
    (RC_CHANNELS_DATA::ID, 0.2),
    (ATTITUDE_DATA::ID, 0.0),
    (LOCAL_POSITION_NED_DATA::ID, 0.0),
    (GLOBAL_POSITION_INT_DATA::ID, 0.0),
];

impl Streams {
    pub(super) fn new(cfg: &GcsConfig, now: Instant) -> Self {
        let fast = Duration::from_secs_f64(1.0 / cfg.telemetry_hz);
        let list = PERIODIC_SENT
            .into_iter()
            .map(|(id, every_s)| {
                let every = if every_s == 0.0 {
                    fast
                } else {
                    Duration::from_secs_f64(every_s)
                };
                (id, every)
            })
            .map(|(id, every)| Stream {
                id,
                default: Some(every),
                interval: Some(every),
                next: now,
            })
            .collect();
        Streams {
            list,
            health: Health {
                fence: true,
                ..Health::default()
            },
            // The first timeout measures it.
            health_at: now.checked_sub(HEALTH_EVERY).unwrap_or(now),
            frames_seen: 0,
            load_permille: 0,
            control_cpu_ns: None,
            fence_breached: false,
            halt_told: false,
        }
    }

    /// When the next periodic message, or the next health check, is due.
    pub(super) fn next_due(&self) -> Option<Instant> {
        let health = self.health_at + HEALTH_EVERY;
        let due = self
            .list
            .iter()
            .filter(|s| s.interval.is_some())
            .map(|s| s.next);
        due.chain([health]).min()
    }

    /// SET_MESSAGE_INTERVAL: negative stops the message, 0 restores its default rate;
    /// faster than [`PACE`] is [`PACE`].
    pub(super) fn set_interval(&mut self, now: Instant, id: u32, interval_us: f32) -> MavResult {
        let Some(s) = self.list.iter_mut().find(|s| s.id == id) else {
            return MavResult::MAV_RESULT_DENIED;
        };
        s.interval = if interval_us < 0.0 {
            None
        } else if interval_us == 0.0 {
            s.default
        } else {
            Some(Duration::from_micros(interval_us as u64).max(PACE))
        };
        s.next = now;
        MavResult::MAV_RESULT_ACCEPTED
    }

    /// The ids of the messages due at `now`, their next times moved on; with `at_most`, no
    /// message more often than that (a radio's download takes the line meanwhile).
    fn take_due(&mut self, now: Instant, at_most: Option<Duration>) -> Vec<u32> {
        let mut due = Vec::new();
        for s in &mut self.list {
            let Some(every) = s.interval else { continue };
            let every = at_most.map_or(every, |slowest| every.max(slowest));
            if now < s.next {
                continue;
            }
            // Keep the rate; after a late call, a whole interval from now (not again at once).
            s.next = if s.next + every > now {
                s.next + every
            } else {
                now + every
            };
            due.push(s.id);
        }
        due
    }
}

/// While a log downloads over a radio, no periodic message goes more often than this.
pub const RADIO_DOWNLOAD_STREAM_EVERY: Duration = Duration::from_millis(500);

impl Connection {
    /// The periodic messages due at `now`.
    pub(super) fn send_due(&mut self, now: Instant) {
        let snap = self.snapshot(now);
        let system_id = self.s.cfg.system_id;
        // Over a radio a download would be starved by the fast streams: they slow to
        // 2 Hz while it runs (attitude and position still flow).
        let radio_download = !self.s.datagrams && self.downloads.next_due().is_some();
        let at_most = radio_download.then_some(RADIO_DOWNLOAD_STREAM_EVERY);
        for id in self.streams.take_due(now, at_most) {
            if let Some(m) = build(id, &snap, system_id) {
                self.send(&m);
            }
        }
    }

    /// REQUEST_MESSAGE: the message now, if it can be built; AVAILABLE_MODES the mode of
    /// 1-based `index` (0: every mode, one message each; past the last: denied).
    pub(super) fn send_by_id(&mut self, now: Instant, id: u32, index: f32) -> MavResult {
        if !REQUESTABLE.contains(&id) {
            return MavResult::MAV_RESULT_DENIED;
        }
        if id == AVAILABLE_MODES_DATA::ID {
            let modes = tm::available_modes();
            let all = index == 0.0;
            let one = (index.fract() == 0.0 && index >= 1.0).then(|| index as usize - 1);
            let chosen: Vec<MavMessage> = match (all, one) {
                (true, _) => modes,
                (false, Some(i)) if i < modes.len() => vec![modes[i].clone()],
                _ => return MavResult::MAV_RESULT_DENIED,
            };
            for m in chosen {
                self.send(&m);
            }
            return MavResult::MAV_RESULT_ACCEPTED;
        }
        match build(id, &self.snapshot(now), self.s.cfg.system_id) {
            Some(m) => {
                self.send(&m);
                MavResult::MAV_RESULT_ACCEPTED
            }
            None => MavResult::MAV_RESULT_FAILED,
        }
    }

    /// Each second (and at the end, `now_anyway`): the sensors', motors' and log folder's
    /// health, the control thread's load, a halt told once.
    pub(super) fn check_health(&mut self, now: Instant, now_anyway: bool) {
        let st = &self.status;
        let h = &mut self.streams;
        if !now_anyway && now < h.health_at + HEALTH_EVERY {
            return;
        }
        let wall_ns = now.saturating_duration_since(h.health_at).as_nanos().max(1) as u64;
        h.health_at = now;
        h.health = Health {
            imu: st.imu_frames > h.frames_seen,
            gps_used: st.gps_used,
            motors: st.escs_answering && st.halt.is_none(),
            estimator: st.live.is_none_or(|l| !l.ratios.outside_gate().any()),
            logging: st.log_problem.is_none(),
            fence: !h.fence_breached,
        };
        h.frames_seen = st.imu_frames;
        if let Some(cpu) = st.control_cpu_ns {
            let busy = cpu.saturating_sub(h.control_cpu_ns.unwrap_or(cpu));
            h.control_cpu_ns = Some(cpu);
            h.load_permille = (1000 * busy / wall_ns).min(1000) as u16;
        }
        if let (Some(reason), false) = (st.halt, h.halt_told) {
            h.halt_told = true;
            let text = format!("halt {}: motors stopped", reason.name());
            self.text(MavSeverity::MAV_SEVERITY_EMERGENCY, &text);
        }
    }
}
