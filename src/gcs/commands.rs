//! A ground station's commands (COMMAND_LONG, COMMAND_INT) mapped onto what uquad does with
//! them: the commander's commands, or requests the link answers itself. Pure.
//!
//! - COMPONENT_ARM_DISARM: 1 → `arm`; 0 → `disarm`; 0 with the force code 21196 → `kill`.
//! - NAV_TAKEOFF: `takeoff` to param 7, the height above the takeoff point in m (as
//!   ArduPilot reads it; NaN: `control.hover_z_m`); COMMAND_INT in a relative or local frame.
//! - NAV_LAND → `land`; NAV_LOITER_UNLIM → `hold` where it is; DO_FLIGHTTERMINATION → `kill`.
//! - DO_SET_MODE (and SET_MODE) in PX4's main and sub modes, DO_SET_STANDARD_MODE: the
//!   commander's command of the same meaning (`gcs::modes`); a mode uquad does not have is
//!   refused, named, never read as another.
//! - DO_MOTOR_TEST → `motor M PCT S` (one motor alone, disarmed; the commander bounds it);
//!   PREFLIGHT_CALIBRATION (gyro, level) → `calibrate`.
//! - REQUEST_MESSAGE, SET_MESSAGE_INTERVAL, REQUEST_AUTOPILOT_CAPABILITIES,
//!   GET_HOME_POSITION: answered by the link.

use super::modes;
use crate::core::commander::Command;
use mavlink::MessageData;
use mavlink::dialects::common::{
    AUTOPILOT_VERSION_DATA, HOME_POSITION_DATA, MavCmd, MavFrame, MavModeFlag, MavResult,
};

/// MAVLink's code for "force" in COMPONENT_ARM_DISARM's param 2.
const FORCE_CODE: f32 = 21196.0;

/// What a command asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// A command for the commander, answered once it has taken or refused it.
    Commander(Command),
    /// Send this message id once.
    Message(u32),
    /// Send this message id every `interval_us` (0: its default rate; negative: never).
    Interval { msg_id: u32, interval_us: f32 },
}

/// A refused command: the result to acknowledge with, and why.
pub type Refusal = (MavResult, String);

/// A command's parameters, whichever message carried them: params 1–4, then x, y, z
/// (COMMAND_INT's integers already as numbers), and the frame (COMMAND_LONG has none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Args {
    pub p: [f32; 7],
    pub frame: Option<MavFrame>,
}

/// Every command [`map`] takes, with what it does (the book's reference lists these; a test
/// checks the list against `map` over every command of the dialect).
#[allow(deprecated)]
pub const HANDLED: &[(MavCmd, &str)] = &[
    (
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        "param 1 = 1: `arm`; 0: `disarm`; 0 with param 2 = 21196 (force): `kill`",
    ),
    (
        MavCmd::MAV_CMD_NAV_TAKEOFF,
        "`takeoff` to param 7 m above the takeoff point (NaN: the profile's height; COMMAND_INT: \
         z in a relative frame, or -z in a local one, a global frame refused); param 7 as an \
         altitude above sea level (PX4's clients) when the ground's is known and only that \
         reading is a height a takeoff may go to, refused when both are",
    ),
    (MavCmd::MAV_CMD_NAV_LAND, "`land`"),
    (
        MavCmd::MAV_CMD_NAV_LOITER_UNLIM,
        "`hold` where the vehicle is",
    ),
    (MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH, "`return`"),
    (MavCmd::MAV_CMD_MISSION_START, "`start` the loaded mission"),
    (
        MavCmd::MAV_CMD_DO_PAUSE_CONTINUE,
        "param 1 = 0: `pause` the mission; 1: `resume` it",
    ),
    (
        MavCmd::MAV_CMD_DO_FLIGHTTERMINATION,
        "param 1 > 0.5: `kill` (the motors stop at once)",
    ),
    (
        MavCmd::MAV_CMD_DO_SET_MODE,
        "param 1 with the custom-mode flag; param 2 PX4's main mode and param 3 its sub mode \
         (or param 2 a packed custom mode): AUTO with LOITER `hold` (`pause` while a mission \
         flies), TAKEOFF `takeoff`, LAND `land`, MISSION `start` (`resume` a paused mission), \
         RTL `return`; a mode uquad does not have is refused, named",
    ),
    (
        MavCmd::MAV_CMD_DO_SET_STANDARD_MODE,
        "param 1 a standard mode: TAKEOFF `takeoff`, LAND `land`, MISSION `start`, \
         SAFE_RECOVERY `return`",
    ),
    (
        MavCmd::MAV_CMD_REQUEST_MESSAGE,
        "sends message param 1 once (the messages the link sends); AVAILABLE_MODES: the mode \
         of index param 2 (1-based; 0: every mode)",
    ),
    (
        MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
        "sends AUTOPILOT_VERSION",
    ),
    (MavCmd::MAV_CMD_GET_HOME_POSITION, "sends HOME_POSITION"),
    (
        MavCmd::MAV_CMD_PREFLIGHT_CALIBRATION,
        "param 1 = 1 (gyro) or param 5 = 1 or 2 (accelerometer, level): `calibrate`, the IMU \
         calibrated at rest again (disarmed, in a profile that calibrates before arming); \
         the other sensors' (magnetometer, barometer, …) are not done, and a request for \
         them alone is unsupported",
    ),
    (
        MavCmd::MAV_CMD_DO_MOTOR_TEST,
        "`motor M PCT S`: motor param 1 (1 to 4: m0 to m3, the board's order; param 6 = 1, a \
         vehicle-specific sequence, is refused) alone, disarmed, at param 3 % of the range \
         above idle (param 2 = 0; or param 2 = 1, param 3 a PWM width, 1000 to 2000 µs read as \
         0 to 100 %) for param 4 s after the ESC's start-up ramp; at most 30 % and 5 s, one \
         motor at a time (param 5 at most 1); a throttle of 0 or `disarm` ends it",
    ),
    (
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        "message param 1 every param 2 µs (at most every 20 ms; 0: its default rate; -1: \
         never)",
    ),
];

// Older ground stations still send the superseded REQUEST_AUTOPILOT_CAPABILITIES,
// GET_HOME_POSITION and MAV_FRAME_GLOBAL_INT: they are taken.
#[allow(deprecated)]
pub fn map(cmd: MavCmd, a: Args) -> Result<Request, Refusal> {
    use Request::*;
    let p = a.p;
    match cmd {
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => arm_disarm(p[0], p[1]),
        MavCmd::MAV_CMD_NAV_TAKEOFF => takeoff(a),
        MavCmd::MAV_CMD_NAV_LAND => Ok(Commander(Command::Land)),
        MavCmd::MAV_CMD_NAV_LOITER_UNLIM => Ok(Commander(Command::Hold(None))),
        MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => Ok(Commander(Command::Return)),
        MavCmd::MAV_CMD_MISSION_START => Ok(Commander(Command::Start)),
        // param 1: 0 pause, 1 continue.
        MavCmd::MAV_CMD_DO_PAUSE_CONTINUE if p[0] == 0.0 => Ok(Commander(Command::Pause)),
        MavCmd::MAV_CMD_DO_PAUSE_CONTINUE if p[0] == 1.0 => Ok(Commander(Command::Resume)),
        MavCmd::MAV_CMD_DO_FLIGHTTERMINATION if p[0] > 0.5 => Ok(Commander(Command::Kill)),
        MavCmd::MAV_CMD_DO_SET_MODE => set_mode(p[0], p[1], p[2]),
        MavCmd::MAV_CMD_DO_SET_STANDARD_MODE => modes::command_of_standard(whole(p[0])?)
            .map(Request::Commander)
            .map_err(denied),
        MavCmd::MAV_CMD_REQUEST_MESSAGE => Ok(Message(whole(p[0])?)),
        MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES => Ok(Message(AUTOPILOT_VERSION_DATA::ID)),
        MavCmd::MAV_CMD_GET_HOME_POSITION => Ok(Message(HOME_POSITION_DATA::ID)),
        MavCmd::MAV_CMD_PREFLIGHT_CALIBRATION => preflight_calibration(p),
        MavCmd::MAV_CMD_DO_MOTOR_TEST => motor_test(p),
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => Ok(Interval {
            msg_id: whole(p[0])?,
            interval_us: p[1],
        }),
        other => Err((
            MavResult::MAV_RESULT_UNSUPPORTED,
            format!("{other:?} is not supported"),
        )),
    }
}

/// PREFLIGHT_CALIBRATION: the gyro (param 1) and the accelerometer or the level (param 5)
/// are the one calibration at rest uquad has; any other sensor's is not supported.
fn preflight_calibration(p: [f32; 7]) -> Result<Request, Refusal> {
    let imu = p[0] == 1.0 || p[4] == 1.0 || p[4] == 2.0;
    if imu {
        return Ok(Request::Commander(Command::Calibrate));
    }
    Err((
        MavResult::MAV_RESULT_UNSUPPORTED,
        "preflight calibration: only the gyro and the level (the IMU at rest)".into(),
    ))
}

/// MOTOR_TEST_THROTTLE_TYPE's percent and PWM, and MOTOR_TEST_ORDER's sequence (MAVLink's
/// enums).
const THROTTLE_PERCENT: f32 = 0.0;
const THROTTLE_PWM: f32 = 1.0;
const ORDER_SEQUENCE: f32 = 1.0;

/// DO_MOTOR_TEST: param 1 the motor (1-based), 2 the throttle's type, 3 the throttle (0
/// stops a test), 4 the time in s, 5 how many motors in turn (0 or 1: this one), 6 the
/// motors' order (default or board: motor 1 is m0; a vehicle-specific sequence is not
/// known here). The commander judges the bounds and the state; here only what cannot be
/// read as one motor's test is refused.
fn motor_test(p: [f32; 7]) -> Result<Request, Refusal> {
    let asked = format!(
        "motor test (motor {}, type {}, throttle {})",
        p[0], p[1], p[2]
    );
    if p[5] == ORDER_SEQUENCE {
        return Err(denied(format!(
            "{asked}: motors in a vehicle-specific sequence are not numbered here: send the \
             board order (motor 1 to 4 = m0 to m3)"
        )));
    }
    // Not a number is not at most 1.
    if p[4].is_nan() || p[4] > 1.0 {
        return Err(denied(format!(
            "{asked}: one motor at a time (param 5 = {} motors asked)",
            p[4]
        )));
    }
    let throttle_pct = match p[1] {
        THROTTLE_PERCENT => p[2],
        THROTTLE_PWM => (p[2] - 1000.0) / 10.0,
        other => {
            return Err((
                MavResult::MAV_RESULT_UNSUPPORTED,
                format!("{asked}: throttle type {other}: only percent (0) and PWM (1)"),
            ));
        }
    };
    if !(p[0].fract() == 0.0 && (0.0..=255.0).contains(&p[0])) {
        return Err(denied(format!("{asked}: the motor is 1 to 4")));
    }
    if !(throttle_pct.is_finite() && p[3].is_finite()) {
        return Err(denied(format!(
            "{asked}: throttle and time must be numbers"
        )));
    }
    Ok(Request::Commander(Command::MotorTest {
        motor: p[0] as u8,
        throttle_pct: shortest(throttle_pct),
        duration_s: shortest(p[3]),
    }))
}

/// `v` as the f64 of its shortest decimal form: 12.3 stays 12.3 in mode.log and in the
/// refusals, not 12.300000190734863 (a finite f32's shortest form always parses).
fn shortest(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(f64::from(v))
}

fn arm_disarm(arm: f32, force: f32) -> Result<Request, Refusal> {
    let c = if arm == 1.0 {
        Command::Arm
    } else if arm != 0.0 {
        return Err(denied(format!("arm/disarm: param 1 is {arm}, not 0 or 1")));
    } else if force == FORCE_CODE {
        Command::Kill
    } else {
        Command::Disarm
    };
    Ok(Request::Commander(c))
}

fn denied(why: String) -> Refusal {
    (MavResult::MAV_RESULT_DENIED, why)
}

fn whole(v: f32) -> Result<u32, Refusal> {
    if v >= 0.0 && v.fract() == 0.0 && v <= 16_777_215.0 {
        Ok(v as u32)
    } else {
        Err(denied(format!("{v} is not a message id")))
    }
}

/// NAV_TAKEOFF's height above the takeoff point: param 7 of COMMAND_LONG, or COMMAND_INT's z
/// in a relative frame (up) or a local one (down: its height is −z); altitudes above sea
/// level are refused.
#[allow(deprecated)]
fn takeoff(a: Args) -> Result<Request, Refusal> {
    use MavFrame::*;
    let z = a.p[6];
    let up = match a.frame {
        None | Some(MAV_FRAME_GLOBAL_RELATIVE_ALT | MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) => z,
        Some(MAV_FRAME_LOCAL_NED | MAV_FRAME_LOCAL_OFFSET_NED) => -z,
        Some(f) => {
            return Err((
                MavResult::MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME,
                format!("takeoff: frame {f:?} not taken; use a relative or local frame"),
            ));
        }
    };
    let height = (!up.is_nan()).then_some(f64::from(up));
    Ok(Request::Commander(Command::Takeoff(height)))
}

/// DO_SET_MODE (and SET_MODE): param 1 the base mode, which must have the custom-mode flag
/// (clients add others: armed, guided, auto... — they state the vehicle's state, and are not
/// read); param 2 PX4's main mode and param 3 its sub mode, or param 2 a whole packed custom
/// mode (SET_MODE's, as HEARTBEAT sends it). `gcs::modes` says which command each mode is;
/// a mode uquad does not have is refused, named.
fn set_mode(base: f32, custom: f32, sub: f32) -> Result<Request, Refusal> {
    let asked = format!("set mode (base {base}, custom {custom}, sub {sub})");
    let custom_bit = u32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
    let whole = |v: f32| v.is_finite() && (0.0..=4_294_967_295.0).contains(&v) && v.fract() == 0.0;
    // An unused sub mode may come as NaN.
    let sub = if sub.is_nan() { 0.0 } else { sub };
    if !whole(base) || !whole(custom) || !whole(sub) {
        return Err(denied(format!("{asked}: not whole numbers")));
    }
    if (base as u32) & custom_bit == 0 {
        return Err(denied(format!(
            "{asked}: only custom modes (PX4's main and sub modes) are taken"
        )));
    }
    let (main, sub) = if custom >= 65_536.0 {
        modes::unpack(custom as u32)
    } else if custom <= 255.0 && sub <= 255.0 {
        (custom as u8, sub as u8)
    } else {
        return Err(denied(format!("{asked}: no such main or sub mode")));
    };
    modes::command_of(main, sub)
        .map(Request::Commander)
        .map_err(|why| denied(format!("{asked}: {why}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::commander::StickMode;

    /// The reference's list is `map`'s: every command of the dialect that `map` does not
    /// answer UNSUPPORTED is listed, and nothing else.
    #[test]
    fn the_handled_list_is_what_map_takes() {
        use num_traits::FromPrimitive;
        // Taken with some parameters: all 0 (pause) or all 1 (flight termination).
        let takes = |c: MavCmd| {
            [0.0, 1.0].into_iter().any(|v| {
                let args = Args {
                    p: [v; 7],
                    frame: None,
                };
                !matches!(map(c, args), Err((MavResult::MAV_RESULT_UNSUPPORTED, _)))
            })
        };
        let taken: Vec<MavCmd> = (0..=u16::MAX)
            .filter_map(|id| MavCmd::from_u32(u32::from(id)))
            .filter(|&c| takes(c))
            .collect();
        let listed: Vec<MavCmd> = HANDLED.iter().map(|(c, _)| *c).collect();
        for c in &taken {
            assert!(listed.contains(c), "{c:?} is taken but not in HANDLED");
        }
        for c in &listed {
            assert!(
                taken.contains(c),
                "{c:?} is in HANDLED but map does not take it"
            );
        }
    }

    fn long(p: [f32; 7]) -> Args {
        Args { p, frame: None }
    }

    #[test]
    #[allow(deprecated)]
    fn commands_map_onto_the_commanders() {
        let arm = |p1, p2| {
            map(
                MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                long([p1, p2, 0., 0., 0., 0., 0.]),
            )
        };
        assert_eq!(arm(1.0, 0.0), Ok(Request::Commander(Command::Arm)));
        assert_eq!(arm(0.0, 0.0), Ok(Request::Commander(Command::Disarm)));
        assert_eq!(arm(0.0, FORCE_CODE), Ok(Request::Commander(Command::Kill)));
        assert!(arm(0.5, 0.0).is_err());
        let takeoff = map(
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            long([0., 0., 0., 0., 0., 0., 1.5]),
        );
        assert_eq!(takeoff, Ok(Request::Commander(Command::Takeoff(Some(1.5)))));
        let nan = map(
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            long([0., 0., 0., 0., 0., 0., f32::NAN]),
        );
        assert_eq!(nan, Ok(Request::Commander(Command::Takeoff(None))));
        let amsl = Args {
            p: [0., 0., 0., 0., 0., 0., 30.0],
            frame: Some(MavFrame::MAV_FRAME_GLOBAL_INT),
        };
        assert!(map(MavCmd::MAV_CMD_NAV_TAKEOFF, amsl).is_err());
        assert_eq!(
            map(MavCmd::MAV_CMD_NAV_LAND, long([0.0; 7])),
            Ok(Request::Commander(Command::Land))
        );
    }

    /// DO_SET_MODE as the common clients send it: QGroundControl's SET_MODE (read as a packed
    /// custom mode), MAVSDK's (base 1 | 128 armed, main, sub) and pymavlink's PX4 map (base
    /// 29: custom, stabilize, guided, auto).
    #[test]
    fn set_mode_takes_px4_modes_as_clients_send_them() {
        let set = |p: [f32; 3]| {
            map(
                MavCmd::MAV_CMD_DO_SET_MODE,
                long([p[0], p[1], p[2], 0., 0., 0., 0.]),
            )
        };
        let hold = Ok(Request::Commander(Command::Hold(None)));
        assert_eq!(set([129.0, 4.0, 3.0]), hold);
        assert_eq!(set([29.0, 4.0, 3.0]), hold);
        assert_eq!(set([1.0, 0x0304_0000 as f32, 0.0]), hold);
        assert_eq!(set([1.0, 4.0, 4.0]), Ok(Request::Commander(Command::Start)));
        assert_eq!(
            set([1.0, 4.0, 5.0]),
            Ok(Request::Commander(Command::Return))
        );
        assert_eq!(set([1.0, 4.0, 6.0]), Ok(Request::Commander(Command::Land)));
        assert_eq!(
            set([1.0, 4.0, f32::NAN]).unwrap_err().0,
            MavResult::MAV_RESULT_DENIED
        );
        // Modes uquad does not have, and requests it cannot read: refused, never guessed.
        assert_eq!(
            set([1.0, 3.0, 0.0]),
            Ok(Request::Commander(Command::Sticks(StickMode::Position)))
        );
        let (result, why) = set([1.0, 6.0, 0.0]).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_DENIED);
        assert!(why.contains("no offboard"), "{why}");
        assert!(set([0.0, 4.0, 3.0]).is_err(), "no custom-mode flag");
        assert!(set([1.0, 4.5, 3.0]).is_err());
        assert!(set([1.5, 4.0, 3.0]).is_err());
        assert!(set([1.0, f32::NAN, 3.0]).is_err());
        assert!(set([1.0, 300.0, 3.0]).is_err());
        let standard = |mode: f32| {
            map(
                MavCmd::MAV_CMD_DO_SET_STANDARD_MODE,
                long([mode, 0., 0., 0., 0., 0., 0.]),
            )
        };
        assert_eq!(standard(5.0), Ok(Request::Commander(Command::Return)));
        assert_eq!(
            standard(4.0),
            Ok(Request::Commander(Command::Sticks(StickMode::Altitude)))
        );
        assert_eq!(standard(3.0).unwrap_err().0, MavResult::MAV_RESULT_DENIED);
    }

    /// DO_MOTOR_TEST as QGroundControl (percent) and Mission Planner (PWM) send it; several
    /// motors in turn, or a throttle from the pilot's stick, refused.
    #[test]
    fn a_motor_test_is_one_motor_at_a_throttle_in_percent() {
        let test = |p: [f32; 6]| {
            map(
                MavCmd::MAV_CMD_DO_MOTOR_TEST,
                long([p[0], p[1], p[2], p[3], p[4], p[5], 0.]),
            )
        };
        let want = |motor, throttle_pct, duration_s| {
            Ok(Request::Commander(Command::MotorTest {
                motor,
                throttle_pct,
                duration_s,
            }))
        };
        assert_eq!(test([1., 0., 10., 3., 0., 2.]), want(1, 10.0, 3.0));
        assert_eq!(test([4., 1., 1150., 2., 1., 0.]), want(4, 15.0, 2.0));
        assert_eq!(test([3., 0., 5., 2., 1., 2.]), want(3, 5.0, 2.0));
        let (result, why) = test([1., 0., 10., 3., 4., 0.]).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_DENIED);
        assert!(why.contains("one motor at a time"), "{why}");
        let (result, _) = test([1., 2., 10., 3., 0., 0.]).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_UNSUPPORTED);
        let (result, why) = test([1., 0., 10., 3., 0., 1.]).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_DENIED);
        assert!(why.contains("board order"), "{why}");
        assert!(test([1., 0., 10., 3., f32::NAN, 0.]).is_err());
        assert_eq!(test([2., 0., 12.3, 1.5, 0., 0.]), want(2, 12.3, 1.5));
        for bad in [[1.5, 0., 10., 3., 0., 0.], [-1., 0., 10., 3., 0., 0.]] {
            assert_eq!(test(bad).unwrap_err().0, MavResult::MAV_RESULT_DENIED);
        }
        assert!(test([1., 0., f32::NAN, 3., 0., 0.]).is_err());
        assert!(test([1., 0., 10., f32::INFINITY, 0., 0.]).is_err());
    }

    #[test]
    fn requests_and_intervals_are_the_links() {
        assert_eq!(
            map(
                MavCmd::MAV_CMD_REQUEST_MESSAGE,
                long([148.0, 0., 0., 0., 0., 0., 0.])
            ),
            Ok(Request::Message(148))
        );
        assert_eq!(
            map(
                MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                long([30.0, 50_000.0, 0., 0., 0., 0., 0.])
            ),
            Ok(Request::Interval {
                msg_id: 30,
                interval_us: 50_000.0
            })
        );
        let (result, _) = map(MavCmd::MAV_CMD_DO_JUMP, long([0.0; 7])).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_UNSUPPORTED);
    }
}
