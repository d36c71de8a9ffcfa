//! Telemetry: the flight's state as MAVLink messages. Pure: the task gathers a [`Snapshot`]
//! and sends what these functions build.
//!
//! Frames: uquad's local frame is x north, y west, z up, its body frame x forward, y left, z
//! up; MAVLink's are north-east-down and forward-right-down. Between the two, y and z change
//! sign: roll stays, pitch and yaw change sign, and so do y and z of every position, speed
//! and rate.

use crate::core::commander::Mode;
use crate::core::ekf::TestRatios;
use crate::core::gps::LiveFix;
use crate::gcs::modes;
use mavlink::dialects::common::*;

/// What the link reports, gathered by the task from the run's shared state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    /// Since the run began, ms.
    pub t_boot_ms: u32,
    pub mode: Mode,
    /// The newest estimate (none until the IMU calibration is done).
    pub state: Option<[f64; 15]>,
    pub ratios: Option<TestRatios>,
    /// The newest GPS fix, and whether it is fresh enough to hold position on.
    pub fix: Option<LiveFix>,
    pub fix_fresh: bool,
    /// The takeoff point in the local frame, m.
    pub home_m: Option<[f64; 3]>,
    /// Before a takeoff point: where the vehicle stood by the first good fix on the ground,
    /// taken again at each arming (local frame, m).
    pub ground_home_m: Option<[f64; 3]>,
    /// Whether an `arm` would pass the pre-arm checks now (none: not checked yet).
    pub prearm: Option<bool>,
    pub health: Health,
    /// The control path's busy share of its period, in tenths of a percent.
    pub load_permille: u16,
    /// Where the loaded mission is, if one is loaded.
    pub mission: Option<MissionStatus>,
    /// The pilot's radio (none: no receiver, or no frame yet).
    pub rc: Option<crate::core::status::RcStatus>,
}

/// Where a mission is, in the ground station's numbering of its items.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionStatus {
    pub seq: u16,
    pub total: u16,
    pub state: MissionState,
}

/// MISSION_CURRENT.
pub fn mission_current(m: &MissionStatus) -> MavMessage {
    MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA {
        seq: m.seq,
        total: m.total,
        mission_state: m.state,
        ..MISSION_CURRENT_DATA::DEFAULT
    })
}

/// Which parts of the vehicle are well.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Health {
    /// IMU frames arriving (gyro, accelerometer, magnetometer, barometer: one device).
    pub imu: bool,
    /// The profile flies with GPS.
    pub gps_used: bool,
    /// Every ESC answering and no halt.
    pub motors: bool,
    /// The estimator's test ratios inside their gates.
    pub estimator: bool,
    /// No geofence breach so far.
    pub fence: bool,
    /// The run folder can be written (the pre-arm probe).
    pub logging: bool,
}

fn armed(mode: Mode) -> bool {
    matches!(mode, Mode::Armed) || mode.airborne()
}

pub fn heartbeat(s: &Snapshot) -> MavMessage {
    let mut base = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    if armed(s.mode) {
        base |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    if s.mode.airborne() {
        base |= MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
            | MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED;
    }
    // A kill is told as PX4 tells a flight termination.
    let system_status = match s.mode {
        Mode::Disarmed => MavState::MAV_STATE_STANDBY,
        Mode::Kill => MavState::MAV_STATE_FLIGHT_TERMINATION,
        _ => MavState::MAV_STATE_ACTIVE,
    };
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: modes::custom_mode(s.mode),
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        // The modes' encoding is PX4's (`gcs::modes` says why).
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: base,
        system_status,
        mavlink_version: 3,
    })
}

/// RC_CHANNELS: the radio's 16 channels as pulse widths, µs; its RSSI field the receiver's
/// link quality scaled to 0–254 (CRSF's; as PX4 fills it), 0 once the receiver is in
/// failsafe, 255 (unknown) from an SBUS receiver, which measures none.
pub fn rc_channels(s: &Snapshot) -> Option<MavMessage> {
    let rc = s.rc?;
    let c = rc.channels_us;
    let rssi = match (rc.lost, rc.link_quality_pct) {
        (true, _) => 0,
        (false, Some(lq)) => (u16::from(lq.min(100)) * 254 / 100) as u8,
        (false, None) => u8::MAX,
    };
    Some(MavMessage::RC_CHANNELS(RC_CHANNELS_DATA {
        time_boot_ms: s.t_boot_ms,
        chancount: c.len() as u8,
        chan1_raw: c[0],
        chan2_raw: c[1],
        chan3_raw: c[2],
        chan4_raw: c[3],
        chan5_raw: c[4],
        chan6_raw: c[5],
        chan7_raw: c[6],
        chan8_raw: c[7],
        chan9_raw: c[8],
        chan10_raw: c[9],
        chan11_raw: c[10],
        chan12_raw: c[11],
        chan13_raw: c[12],
        chan14_raw: c[13],
        chan15_raw: c[14],
        chan16_raw: c[15],
        // Unused, as the message says them.
        chan17_raw: u16::MAX,
        chan18_raw: u16::MAX,
        rssi,
    }))
}

/// CURRENT_MODE: the mode as the standard modes and PX4's custom mode say it.
pub fn current_mode(s: &Snapshot) -> MavMessage {
    let custom = modes::custom_mode(s.mode);
    MavMessage::CURRENT_MODE(CURRENT_MODE_DATA {
        custom_mode: custom,
        intended_custom_mode: custom,
        standard_mode: modes::standard_mode(s.mode),
    })
}

/// AVAILABLE_MODES: every mode a ground station may ask for, and the kill's (not
/// selectable), one message each.
pub fn available_modes() -> Vec<MavMessage> {
    let n = modes::SELECTABLE.len() as u8;
    modes::SELECTABLE
        .iter()
        .enumerate()
        .map(|(i, m)| {
            MavMessage::AVAILABLE_MODES(AVAILABLE_MODES_DATA {
                custom_mode: m.custom_mode,
                properties: m.properties,
                number_modes: n,
                mode_index: i as u8 + 1,
                standard_mode: m.standard,
                mode_name: m.name.into(),
            })
        })
        .collect()
}

pub fn sys_status(s: &Snapshot) -> MavMessage {
    use MavSysStatusSensor as S;
    let imu = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
        | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
        | S::MAV_SYS_STATUS_SENSOR_3D_MAG
        | S::MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE;
    let control = S::MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
        | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
        | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
        | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL;
    let h = s.health;
    let gps = S::MAV_SYS_STATUS_SENSOR_GPS;
    let motors = S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
    let fence = S::MAV_SYS_STATUS_GEOFENCE;
    let logging = S::MAV_SYS_STATUS_LOGGING;
    let prearm = S::MAV_SYS_STATUS_PREARM_CHECK;
    let mut present = imu | control | motors | fence | logging;
    if h.gps_used {
        present |= gps;
    }
    if s.prearm.is_some() {
        present |= prearm;
    }
    let mut health = S::empty();
    let mut set = |ok: bool, bits: S| {
        if ok {
            health |= bits;
        }
    };
    set(h.imu, imu);
    set(h.gps_used && s.fix_fresh, gps);
    set(h.motors, motors);
    set(h.estimator && h.imu, control);
    set(h.fence, fence);
    set(h.logging, logging);
    // Healthy while the checks pass, the IMU's frames arrive (the check runs at a frame: with
    // none, its last word is stale) and the vehicle stands disarmed.
    set(
        s.prearm == Some(true) && h.imu && s.mode == Mode::Disarmed,
        prearm,
    );
    MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        onboard_control_sensors_present: present,
        onboard_control_sensors_enabled: present,
        onboard_control_sensors_health: health,
        load: s.load_permille,
        // No battery is measured.
        voltage_battery: u16::MAX,
        current_battery: -1,
        battery_remaining: -1,
        ..SYS_STATUS_DATA::DEFAULT
    })
}

pub use crate::core::math::wrap_pi;

pub fn attitude(s: &Snapshot) -> Option<MavMessage> {
    let x = s.state?;
    Some(MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms: s.t_boot_ms,
        roll: x[3] as f32,
        pitch: -x[4] as f32,
        yaw: wrap_pi(-x[5]) as f32,
        rollspeed: x[9] as f32,
        pitchspeed: -x[10] as f32,
        yawspeed: -x[11] as f32,
    }))
}

/// Position and velocity, north-east-down, m and m/s (also the ULog export's).
pub fn ned(x: &[f64; 15]) -> ([f64; 3], [f64; 3]) {
    let r = crate::core::math::rotation(x[3], x[4], x[5]);
    let v: [f64; 3] = std::array::from_fn(|i| r[i][0] * x[6] + r[i][1] * x[7] + r[i][2] * x[8]);
    ([x[0], -x[1], -x[2]], [v[0], -v[1], -v[2]])
}

pub fn local_position(s: &Snapshot) -> Option<MavMessage> {
    let (p, v) = ned(&s.state?);
    Some(MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
        time_boot_ms: s.t_boot_ms,
        x: p[0] as f32,
        y: p[1] as f32,
        z: p[2] as f32,
        vx: v[0] as f32,
        vy: v[1] as f32,
        vz: v[2] as f32,
    }))
}

/// Latitude, longitude (degrees) and altitude above sea level (m, when the fix has one) of
/// local point `p_m`, from the newest fix: its own position in both frames anchors them.
fn global_of(fix: &LiveFix, p_m: [f64; 3]) -> ([f64; 2], Option<f64>) {
    let f = &fix.sample;
    let offset = [p_m[0] - f.xy_m[0], p_m[1] - f.xy_m[1]];
    let deg = crate::core::gps::offset_deg([fix.fix.lat_deg, fix.fix.lon_deg], offset);
    let alt = match (fix.fix.alt_m, f.z_m) {
        (Some(a), Some(z)) => Some(a + p_m[2] - z),
        _ => None,
    };
    (deg, alt)
}

fn e7(deg: f64) -> i32 {
    (deg * 1e7).round() as i32
}

fn mm(m: f64) -> i32 {
    (m * 1000.0).round() as i32
}

pub fn global_position(s: &Snapshot) -> Option<MavMessage> {
    let Some(x) = s.state else {
        return fix_position(s);
    };
    let fix = s.fix?;
    let (_, v) = ned(&x);
    let ([lat, lon], alt) = global_of(&fix, [x[0], x[1], x[2]]);
    let home_z = s.home_m.map_or(0.0, |h| h[2]);
    let cm_s = |v: f64| (v * 100.0).round().clamp(-32_767.0, 32_767.0) as i16;
    let yaw_deg = wrap_pi(-x[5]).to_degrees().rem_euclid(360.0);
    Some(MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
        time_boot_ms: s.t_boot_ms,
        lat: e7(lat),
        lon: e7(lon),
        alt: alt.map_or(0, mm),
        relative_alt: mm(x[2] - home_z),
        vx: cm_s(v[0]),
        vy: cm_s(v[1]),
        vz: cm_s(v[2]),
        hdg: ((yaw_deg * 100.0).round() as u16) % 36_000,
    }))
}

/// GLOBAL_POSITION_INT before the estimate runs: the fresh 3-D fix itself, its height
/// relative to where the vehicle stood (it is on the ground), its velocity if it gives one,
/// the heading unknown.
fn fix_position(s: &Snapshot) -> Option<MavMessage> {
    let fix = s.fix.filter(|f| s.fix_fresh && f.fix.mode >= 3)?;
    let z = fix.sample.z_m?;
    let ground_z = s.ground_home_m.map_or(z, |h| h[2]);
    let v = fix.sample.vel_m_s.unwrap_or([0.0; 3]);
    let cm_s = |v: f64| (v * 100.0).round().clamp(-32_767.0, 32_767.0) as i16;
    Some(MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
        time_boot_ms: s.t_boot_ms,
        lat: e7(fix.fix.lat_deg),
        lon: e7(fix.fix.lon_deg),
        alt: fix.fix.alt_m.map_or(0, mm),
        relative_alt: mm(z - ground_z),
        // North, west, up to north, east, down.
        vx: cm_s(v[0]),
        vy: cm_s(-v[1]),
        vz: cm_s(-v[2]),
        hdg: u16::MAX,
    }))
}

pub fn gps_raw(s: &Snapshot) -> Option<MavMessage> {
    let f = s.fix?;
    let fix_type = match f.fix.mode {
        3.. => GpsFixType::GPS_FIX_TYPE_3D_FIX,
        2 => GpsFixType::GPS_FIX_TYPE_2D_FIX,
        _ => GpsFixType::GPS_FIX_TYPE_NO_FIX,
    };
    Some(MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
        time_usec: u64::try_from(f.stamp_us).unwrap_or(0),
        lat: e7(f.fix.lat_deg),
        lon: e7(f.fix.lon_deg),
        alt: f.fix.alt_m.map_or(0, mm),
        // gpsd gives an error estimate, not dilutions, speeds or satellites: unknown.
        eph: u16::MAX,
        epv: u16::MAX,
        vel: u16::MAX,
        cog: u16::MAX,
        fix_type,
        satellites_visible: u8::MAX,
        h_acc: f.fix.eph_m.map_or(0, |e| (e * 1000.0).round() as u32),
        ..GPS_RAW_INT_DATA::DEFAULT
    }))
}

/// The takeoff point, once it and a fix are known (a home without a place on the Earth
/// would be drawn at 0° 0°).
pub fn home_position(s: &Snapshot) -> Option<MavMessage> {
    let h = s.home_m.or(s.ground_home_m)?;
    let (deg, alt) = global_of(&s.fix?, h);
    Some(MavMessage::HOME_POSITION(HOME_POSITION_DATA {
        latitude: e7(deg[0]),
        longitude: e7(deg[1]),
        altitude: alt.map_or(0, mm),
        x: h[0] as f32,
        y: -h[1] as f32,
        z: -h[2] as f32,
        q: [1.0, 0.0, 0.0, 0.0],
        ..HOME_POSITION_DATA::DEFAULT
    }))
}

pub fn landed_state(mode: Mode) -> MavLandedState {
    match mode {
        Mode::Disarmed | Mode::Armed => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
        Mode::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
        Mode::Hold | Mode::Mission | Mode::Return | Mode::Position | Mode::Altitude => {
            MavLandedState::MAV_LANDED_STATE_IN_AIR
        }
        Mode::Land => MavLandedState::MAV_LANDED_STATE_LANDING,
        // The motors were cut: where the vehicle is now is not known.
        Mode::Kill => MavLandedState::MAV_LANDED_STATE_UNDEFINED,
    }
}

pub fn extended_sys_state(s: &Snapshot) -> MavMessage {
    MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
        vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
        landed_state: landed_state(s.mode),
    })
}

/// The innovation test ratios of the estimator's groups: attitude as the magnetometer's
/// (its heading and tilt), altitude as the vertical position's, GPS as the horizontal one's.
pub fn estimator_status(s: &Snapshot) -> Option<MavMessage> {
    let r = s.ratios?;
    use EstimatorStatusFlags as F;
    let mut flags = F::ESTIMATOR_ATTITUDE
        | F::ESTIMATOR_VELOCITY_HORIZ
        | F::ESTIMATOR_VELOCITY_VERT
        | F::ESTIMATOR_POS_HORIZ_REL
        | F::ESTIMATOR_POS_VERT_ABS;
    if s.fix_fresh {
        flags |= F::ESTIMATOR_POS_HORIZ_ABS;
    }
    Some(MavMessage::ESTIMATOR_STATUS(ESTIMATOR_STATUS_DATA {
        time_usec: u64::from(s.t_boot_ms) * 1000,
        mag_ratio: r.attitude as f32,
        pos_vert_ratio: r.altitude as f32,
        pos_horiz_ratio: r.gps.unwrap_or(0.0) as f32,
        flags,
        ..ESTIMATOR_STATUS_DATA::DEFAULT
    }))
}

/// Bytes of text in one STATUSTEXT.
const STATUSTEXT_LEN: usize = 50;

/// `text` as STATUSTEXT messages: one, or chunks of 50 bytes sharing `id` (MAVLink 2's
/// long-text rule; a text of exactly 50 bytes is followed by an empty chunk to end it).
pub fn statustext(severity: MavSeverity, text: &str, id: u16) -> Vec<MavMessage> {
    let bytes = text.as_bytes();
    if bytes.len() < STATUSTEXT_LEN {
        return vec![statustext_chunk(severity, bytes, 0, 0)];
    }
    let mut chunks: Vec<&[u8]> = bytes.chunks(STATUSTEXT_LEN).collect();
    if bytes.len().is_multiple_of(STATUSTEXT_LEN) {
        chunks.push(&[]);
    }
    chunks
        .into_iter()
        .enumerate()
        .map(|(i, c)| statustext_chunk(severity, c, id, i.min(255) as u8))
        .collect()
}

fn statustext_chunk(severity: MavSeverity, text: &[u8], id: u16, seq: u8) -> MavMessage {
    let mut buf = [0u8; STATUSTEXT_LEN];
    buf[..text.len()].copy_from_slice(text);
    MavMessage::STATUSTEXT(STATUSTEXT_DATA {
        severity,
        text: buf.into(),
        id,
        chunk_seq: seq,
    })
}

pub fn autopilot_version(system_id: u8) -> MavMessage {
    use MavProtocolCapability as C;
    let version = |s: &str| s.parse::<u32>().unwrap_or(0);
    let (major, minor, patch) = (
        version(env!("CARGO_PKG_VERSION_MAJOR")),
        version(env!("CARGO_PKG_VERSION_MINOR")),
        version(env!("CARGO_PKG_VERSION_PATCH")),
    );
    MavMessage::AUTOPILOT_VERSION(AUTOPILOT_VERSION_DATA {
        capabilities: C::MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | C::MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | C::MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | C::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST,
        // Version as MAVLink packs it: major, minor, patch, release type (255: official).
        flight_sw_version: (major << 24) | (minor << 16) | (patch << 8) | 255,
        uid: u64::from(system_id),
        ..AUTOPILOT_VERSION_DATA::DEFAULT
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::gps::{Fix, GpsSample};

    fn snapshot() -> Snapshot {
        Snapshot {
            t_boot_ms: 1000,
            mode: Mode::Hold,
            state: None,
            ratios: None,
            fix: None,
            fix_fresh: false,
            home_m: None,
            ground_home_m: None,
            prearm: None,
            health: Health::default(),
            load_permille: 0,
            mission: None,
            rc: None,
        }
    }

    #[test]
    fn heartbeats_say_armed_and_mode() {
        let mut s = snapshot();
        let MavMessage::HEARTBEAT(h) = heartbeat(&s) else {
            panic!()
        };
        assert!(
            h.base_mode
                .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)
        );
        assert_eq!(h.custom_mode, modes::custom_mode(Mode::Hold));
        assert_eq!(h.autopilot, MavAutopilot::MAV_AUTOPILOT_PX4);
        s.mode = Mode::Disarmed;
        let MavMessage::HEARTBEAT(h) = heartbeat(&s) else {
            panic!()
        };
        assert!(
            !h.base_mode
                .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)
        );
        assert_eq!(h.mavtype, MavType::MAV_TYPE_QUADROTOR);
    }

    #[test]
    fn frames_turn_from_north_west_up_to_north_east_down() {
        let mut x = [0.0; 15];
        // 1 m north, 2 m west, 3 m up; yawed 0.5 rad towards the west; moving forward at 1 m/s.
        x[0] = 1.0;
        x[1] = 2.0;
        x[2] = 3.0;
        x[5] = 0.5;
        x[6] = 1.0;
        let s = Snapshot {
            state: Some(x),
            ..snapshot()
        };
        let Some(MavMessage::LOCAL_POSITION_NED(p)) = local_position(&s) else {
            panic!()
        };
        assert_eq!((p.x, p.y, p.z), (1.0, -2.0, -3.0));
        // Forward at yaw 0.5 rad west of north: north cos 0.5, east −sin 0.5.
        assert!((p.vx - 0.5f32.cos()).abs() < 1e-6 && (p.vy + 0.5f32.sin()).abs() < 1e-6);
        let Some(MavMessage::ATTITUDE(a)) = attitude(&s) else {
            panic!()
        };
        assert!((a.yaw + 0.5).abs() < 1e-6);
    }

    #[test]
    fn global_positions_follow_the_newest_fix() {
        let mut x = [0.0; 15];
        x[0] = 11.0; // 1 m north of the fix
        x[2] = 2.0;
        let fix = LiveFix {
            seq: 1,
            fix: Fix {
                mode: 3,
                lat_deg: -34.9,
                lon_deg: -56.1,
                alt_m: Some(30.0),
                eph_m: Some(1.5),
            },
            sample: GpsSample::at([10.0, 0.0, 1.0]),
            stamp_us: 0,
        };
        let s = Snapshot {
            state: Some(x),
            fix: Some(fix),
            home_m: Some([0.0, 0.0, 0.5]),
            ground_home_m: None,
            prearm: None,
            ..snapshot()
        };
        let Some(MavMessage::GLOBAL_POSITION_INT(g)) = global_position(&s) else {
            panic!()
        };
        // 1 m north is 1/111 195 of a degree: 90 units of 1e-7 degree.
        assert_eq!(g.lat, e7(-34.9) + 90);
        assert_eq!(g.lon, e7(-56.1));
        assert_eq!(g.alt, 31_000);
        assert_eq!(g.relative_alt, 1_500);
        let Some(MavMessage::GPS_RAW_INT(r)) = gps_raw(&s) else {
            panic!()
        };
        assert_eq!(r.h_acc, 1500);
    }

    #[test]
    fn long_texts_are_sent_in_chunks() {
        let one = statustext(MavSeverity::MAV_SEVERITY_INFO, "short", 7);
        assert_eq!(one.len(), 1);
        let text = "x".repeat(120);
        let chunks = statustext(MavSeverity::MAV_SEVERITY_WARNING, &text, 7);
        assert_eq!(chunks.len(), 3);
        let MavMessage::STATUSTEXT(last) = &chunks[2] else {
            panic!()
        };
        assert_eq!((last.id, last.chunk_seq), (7, 2));
        assert_eq!(
            statustext(MavSeverity::MAV_SEVERITY_INFO, &"y".repeat(50), 1).len(),
            2
        );
    }
}
