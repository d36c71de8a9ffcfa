//! A ground station's commands (COMMAND_LONG, COMMAND_INT) mapped onto what uquad does with
//! them: the commander's commands, or requests the link answers itself. Pure.
//!
//! - COMPONENT_ARM_DISARM: 1 → `arm`; 0 → `disarm`; 0 with the force code 21196 → `kill`.
//! - NAV_TAKEOFF: `takeoff` to param 7, the height above the takeoff point in m (as
//!   ArduPilot reads it; NaN: `control.hover_z_m`); COMMAND_INT in a relative or local frame.
//! - NAV_LAND → `land`; NAV_LOITER_UNLIM → `hold` where it is; DO_FLIGHTTERMINATION → `kill`.
//! - DO_SET_MODE with a custom mode (HEARTBEAT's numbering): hold → `hold`, land → `land`;
//!   the others are entered by their own commands. A sub mode, or base-mode flags other than
//!   custom-mode-enabled and armed, are refused: never read as another mode.
//! - REQUEST_MESSAGE, SET_MESSAGE_INTERVAL, REQUEST_AUTOPILOT_CAPABILITIES,
//!   GET_HOME_POSITION: answered by the link.

use super::telemetry::mode_of_custom;
use crate::core::commander::{Command, Mode};
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
        "`takeoff` to param 7 m above the takeoff point (COMMAND_INT: z in a relative frame, \
         or -z in a local one; NaN: the profile's height); altitudes above sea level refused",
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
        "a custom mode in HEARTBEAT's numbering (base mode: custom-mode flag, optionally \
         armed; no sub mode): hold, land, mission (`start`) or return; the others are \
         entered by their own commands",
    ),
    (
        MavCmd::MAV_CMD_REQUEST_MESSAGE,
        "sends message param 1 once (the messages the link sends)",
    ),
    (
        MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
        "sends AUTOPILOT_VERSION",
    ),
    (MavCmd::MAV_CMD_GET_HOME_POSITION, "sends HOME_POSITION"),
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
        MavCmd::MAV_CMD_REQUEST_MESSAGE => Ok(Message(whole(p[0])?)),
        MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES => Ok(Message(AUTOPILOT_VERSION_DATA::ID)),
        MavCmd::MAV_CMD_GET_HOME_POSITION => Ok(Message(HOME_POSITION_DATA::ID)),
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

/// DO_SET_MODE (and SET_MODE): a custom mode in HEARTBEAT's numbering, with no sub mode and
/// no base-mode flag but custom-mode-enabled (and the armed flag, which states the vehicle's
/// state rather than asks for one). Anything else would be guessing at another numbering (a
/// PX4 main and sub mode, a base mode's manual or guided flags): refused, never mapped.
fn set_mode(base: f32, custom: f32, sub: f32) -> Result<Request, Refusal> {
    let asked = format!("set mode (base {base}, custom {custom}, sub {sub})");
    let custom_bit = u32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
    let armed_bit = u32::from(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED.bits());
    let whole = |v: f32| (0.0..=16_777_215.0).contains(&v) && v.fract() == 0.0;
    if !whole(base) || !whole(custom) {
        return Err(denied(format!("{asked}: not whole numbers")));
    }
    // The base mode is a bit field sent as a float.
    let base_bits = base as u32;
    if base_bits & custom_bit == 0 {
        return Err(denied(format!(
            "{asked}: only custom modes (HEARTBEAT's numbering) are taken"
        )));
    }
    if base_bits & !(custom_bit | armed_bit) != 0 {
        return Err(denied(format!(
            "{asked}: base-mode flags other than custom mode and armed are not handled"
        )));
    }
    // An unused parameter may be sent as NaN.
    if !(sub == 0.0 || sub.is_nan()) {
        return Err(denied(format!(
            "{asked}: uquad's modes have no sub modes (is this another autopilot's numbering?)"
        )));
    }
    match mode_of_custom(custom as u32) {
        Some(Mode::Hold) => Ok(Request::Commander(Command::Hold(None))),
        Some(Mode::Land) => Ok(Request::Commander(Command::Land)),
        Some(Mode::Mission) => Ok(Request::Commander(Command::Start)),
        Some(Mode::Return) => Ok(Request::Commander(Command::Return)),
        Some(m) => Err(denied(format!(
            "{asked}: {} is entered by its own command (arm, takeoff, disarm, kill)",
            m.name()
        ))),
        None => Err(denied(format!("{asked}: no custom mode {custom}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn set_mode_takes_hold_and_land_by_custom_mode() {
        let set = |custom| {
            map(
                MavCmd::MAV_CMD_DO_SET_MODE,
                long([1.0, custom, 0., 0., 0., 0., 0.]),
            )
        };
        assert_eq!(set(3.0), Ok(Request::Commander(Command::Hold(None))));
        assert_eq!(set(4.0), Ok(Request::Commander(Command::Land)));
        assert!(set(1.0).is_err());
        assert!(set(99.0).is_err());
        let no_custom = map(
            MavCmd::MAV_CMD_DO_SET_MODE,
            long([0.0, 3.0, 0., 0., 0., 0., 0.]),
        );
        assert!(no_custom.is_err());
    }

    #[test]
    fn set_mode_in_another_numbering_is_refused_not_mapped() {
        let set = |p: [f32; 3]| {
            map(
                MavCmd::MAV_CMD_DO_SET_MODE,
                long([p[0], p[1], p[2], 0., 0., 0., 0.]),
            )
        };
        // PX4's AUTO (main 4) with sub mode LOITER (3): uquad's 4 is land; it must not land.
        let (result, why) = set([129.0, 4.0, 3.0]).unwrap_err();
        assert_eq!(result, MavResult::MAV_RESULT_DENIED);
        assert!(
            why.contains("sub 3") && why.contains("no sub modes"),
            "{why}"
        );
        // Base-mode flags uquad does not handle (guided, auto, stabilize, manual input).
        for base in [
            1.0 + 8.0,
            1.0 + 4.0,
            1.0 + 16.0,
            1.0 + 64.0,
            1.0 + 2.0,
            1.0 + 32.0,
        ] {
            assert!(set([base, 3.0, 0.0]).is_err(), "base {base}");
        }
        // Not whole numbers: refused rather than truncated.
        assert!(set([1.0, 3.5, 0.0]).is_err());
        assert!(set([1.5, 3.0, 0.0]).is_err());
        assert!(set([1.0, f32::NAN, 0.0]).is_err());
        // The armed flag states the vehicle's state; an unused sub mode may come as NaN.
        assert_eq!(
            set([129.0, 3.0, f32::NAN]),
            Ok(Request::Commander(Command::Hold(None)))
        );
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
