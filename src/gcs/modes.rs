//! uquad's modes as ground stations name and set them. HEARTBEAT says autopilot PX4 and packs
//! the mode as PX4 does (main mode in bits 16–23, sub mode in 24–31): QGroundControl picks its
//! PX4 plugin by the autopilot type (a generic autopilot's modes it can neither name nor set),
//! MAVSDK decodes every non-ArduPilot custom mode as PX4's, and pymavlink/MAVProxy read PX4's
//! for a PX4 autopilot (a generic quadrotor's numbers they name as ArduCopter's). The standard
//! modes (AVAILABLE_MODES, CURRENT_MODE, DO_SET_STANDARD_MODE) name them too, for the clients
//! that read those.
//!
//! | uquad | PX4 (main, sub) | standard |
//! |---|---|---|
//! | disarmed, armed (on the ground) | AUTO, LOITER ("Hold"; PX4's own on the ground) | none |
//! | takeoff | AUTO, TAKEOFF | TAKEOFF |
//! | hold | AUTO, LOITER | none (PX4's hold is not the standard position mode) |
//! | land | AUTO, LAND | LAND |
//! | mission | AUTO, MISSION | MISSION |
//! | return | AUTO, RTL | SAFE_RECOVERY |
//! | position (the sticks) | POSCTL | POSITION_HOLD |
//! | altitude (the sticks) | ALTCTL | ALTITUDE_HOLD |
//! | kill | MANUAL, none, with MAV_STATE_FLIGHT_TERMINATION (as PX4 tells a termination) | none |
//!
//! The ground's modes are told apart from hold by the armed flag and EXTENDED_SYS_STATE's
//! landed state. A request to enter a mode maps onto the commander's command of the same
//! meaning; a mode uquad does not have (manual, acro, offboard...) is refused with its name.

use crate::core::commander::{Command, Mode, StickMode};
use mavlink::dialects::common::{MavModeProperty, MavStandardMode};

/// PX4's main modes and its AUTO sub modes (`px4_custom_mode.h`).
pub const MAIN_MANUAL: u8 = 1;
pub const MAIN_ALTCTL: u8 = 2;
pub const MAIN_POSCTL: u8 = 3;
pub const MAIN_AUTO: u8 = 4;
pub const MAIN_ACRO: u8 = 5;
pub const MAIN_OFFBOARD: u8 = 6;
pub const MAIN_STABILIZED: u8 = 7;
pub const SUB_READY: u8 = 1;
pub const SUB_TAKEOFF: u8 = 2;
pub const SUB_LOITER: u8 = 3;
pub const SUB_MISSION: u8 = 4;
pub const SUB_RTL: u8 = 5;
pub const SUB_LAND: u8 = 6;

/// A PX4 custom mode from its main and sub mode.
pub const fn pack(main: u8, sub: u8) -> u32 {
    ((sub as u32) << 24) | ((main as u32) << 16)
}

/// The main and sub mode of a packed custom mode.
pub fn unpack(custom: u32) -> (u8, u8) {
    (((custom >> 16) & 0xff) as u8, (custom >> 24) as u8)
}

/// HEARTBEAT's custom mode for uquad's mode.
pub fn custom_mode(mode: Mode) -> u32 {
    match mode {
        Mode::Disarmed | Mode::Armed | Mode::Hold => pack(MAIN_AUTO, SUB_LOITER),
        Mode::Takeoff => pack(MAIN_AUTO, SUB_TAKEOFF),
        Mode::Land => pack(MAIN_AUTO, SUB_LAND),
        Mode::Mission => pack(MAIN_AUTO, SUB_MISSION),
        Mode::Return => pack(MAIN_AUTO, SUB_RTL),
        Mode::Kill => pack(MAIN_MANUAL, 0),
        Mode::Position => pack(MAIN_POSCTL, 0),
        Mode::Altitude => pack(MAIN_ALTCTL, 0),
    }
}

/// The standard mode uquad's mode is, if any.
pub fn standard_mode(mode: Mode) -> MavStandardMode {
    use MavStandardMode::*;
    match mode {
        Mode::Takeoff => MAV_STANDARD_MODE_TAKEOFF,
        Mode::Land => MAV_STANDARD_MODE_LAND,
        Mode::Mission => MAV_STANDARD_MODE_MISSION,
        Mode::Return => MAV_STANDARD_MODE_SAFE_RECOVERY,
        Mode::Position => MAV_STANDARD_MODE_POSITION_HOLD,
        Mode::Altitude => MAV_STANDARD_MODE_ALTITUDE_HOLD,
        _ => MAV_STANDARD_MODE_NON_STANDARD,
    }
}

/// A mode AVAILABLE_MODES lists: its name, its custom mode, its standard mode, and the
/// commander's command that enters it (none: a ground station may not ask for it).
pub struct Selectable {
    pub name: &'static str,
    pub custom_mode: u32,
    pub standard: MavStandardMode,
    pub command: Option<Command>,
    pub properties: MavModeProperty,
}

/// The modes AVAILABLE_MODES lists, in its order (1-based there): those a ground station may
/// ask for, and the kill's, which CURRENT_MODE may name but no request enters.
pub const SELECTABLE: [Selectable; 8] = [
    Selectable {
        name: "Hold",
        custom_mode: pack(MAIN_AUTO, SUB_LOITER),
        standard: MavStandardMode::MAV_STANDARD_MODE_NON_STANDARD,
        command: Some(Command::Hold(None)),
        properties: MavModeProperty::MAV_MODE_PROPERTY_AUTO_MODE,
    },
    Selectable {
        name: "Takeoff",
        custom_mode: pack(MAIN_AUTO, SUB_TAKEOFF),
        standard: MavStandardMode::MAV_STANDARD_MODE_TAKEOFF,
        command: Some(Command::Takeoff(None)),
        properties: MavModeProperty::MAV_MODE_PROPERTY_AUTO_MODE,
    },
    Selectable {
        name: "Land",
        custom_mode: pack(MAIN_AUTO, SUB_LAND),
        standard: MavStandardMode::MAV_STANDARD_MODE_LAND,
        command: Some(Command::Land),
        properties: MavModeProperty::MAV_MODE_PROPERTY_AUTO_MODE,
    },
    Selectable {
        name: "Mission",
        custom_mode: pack(MAIN_AUTO, SUB_MISSION),
        standard: MavStandardMode::MAV_STANDARD_MODE_MISSION,
        command: Some(Command::Start),
        properties: MavModeProperty::MAV_MODE_PROPERTY_AUTO_MODE,
    },
    Selectable {
        name: "Return",
        custom_mode: pack(MAIN_AUTO, SUB_RTL),
        standard: MavStandardMode::MAV_STANDARD_MODE_SAFE_RECOVERY,
        command: Some(Command::Return),
        properties: MavModeProperty::MAV_MODE_PROPERTY_AUTO_MODE,
    },
    Selectable {
        name: "Position",
        custom_mode: pack(MAIN_POSCTL, 0),
        standard: MavStandardMode::MAV_STANDARD_MODE_POSITION_HOLD,
        command: Some(Command::Sticks(StickMode::Position)),
        properties: MavModeProperty::empty(),
    },
    Selectable {
        name: "Altitude",
        custom_mode: pack(MAIN_ALTCTL, 0),
        standard: MavStandardMode::MAV_STANDARD_MODE_ALTITUDE_HOLD,
        command: Some(Command::Sticks(StickMode::Altitude)),
        properties: MavModeProperty::empty(),
    },
    Selectable {
        name: "Terminated",
        custom_mode: pack(MAIN_MANUAL, 0),
        standard: MavStandardMode::MAV_STANDARD_MODE_NON_STANDARD,
        command: None,
        properties: MavModeProperty::MAV_MODE_PROPERTY_NOT_USER_SELECTABLE,
    },
];

/// The command entering PX4 mode (`main`, `sub`), or why uquad has no such mode.
pub fn command_of(main: u8, sub: u8) -> Result<Command, String> {
    let custom = pack(main, sub);
    if let Some(c) = SELECTABLE
        .iter()
        .find(|s| s.custom_mode == custom)
        .and_then(|s| s.command)
    {
        return Ok(c);
    }
    let name = match (main, sub) {
        (MAIN_AUTO, SUB_READY) => "ready (entered by arming, or by landing)",
        (MAIN_AUTO, _) => "this auto sub mode",
        (MAIN_MANUAL, _) => "manual",
        (MAIN_ALTCTL, _) => "altitude with this sub mode",
        (MAIN_POSCTL, _) => "position with this sub mode",
        (MAIN_ACRO, _) => "acro",
        (MAIN_OFFBOARD, _) => "offboard",
        (MAIN_STABILIZED, _) => "stabilized",
        _ => "this mode",
    };
    Err(format!(
        "main mode {main}, sub mode {sub}: uquad has no {name}; it takes Hold, Takeoff, Land, \
         Mission, Return, Position and Altitude"
    ))
}

/// The command entering standard mode `mode`, or why uquad has none.
pub fn command_of_standard(mode: u32) -> Result<Command, String> {
    SELECTABLE
        .iter()
        .find(|s| s.standard as u32 == mode && mode != 0)
        .and_then(|s| s.command)
        .ok_or_else(|| {
            format!(
                "standard mode {mode}: uquad takes position hold (1), altitude hold (4), \
                 takeoff (8), land (7), mission (6) and safe recovery (5)"
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_mode_round_trips_through_its_packing() {
        for m in Mode::ALL {
            let (main, sub) = unpack(custom_mode(m));
            assert_eq!(pack(main, sub), custom_mode(m));
        }
        assert_eq!(custom_mode(Mode::Hold), 0x0304_0000);
        assert_eq!(custom_mode(Mode::Return), 0x0504_0000);
    }

    #[test]
    fn requests_enter_the_mode_they_name_or_are_refused() {
        assert_eq!(command_of(4, 3), Ok(Command::Hold(None)));
        assert_eq!(command_of(4, 4), Ok(Command::Start));
        assert_eq!(command_of(4, 5), Ok(Command::Return));
        assert_eq!(command_of(4, 6), Ok(Command::Land));
        assert_eq!(command_of(4, 2), Ok(Command::Takeoff(None)));
        assert_eq!(command_of(3, 0), Ok(Command::Sticks(StickMode::Position)));
        assert_eq!(command_of(2, 0), Ok(Command::Sticks(StickMode::Altitude)));
        let why = command_of(5, 0).unwrap_err();
        assert!(why.contains("no acro"), "{why}");
        assert_eq!(
            command_of_standard(1),
            Ok(Command::Sticks(StickMode::Position))
        );
        assert!(command_of(4, 1).is_err());
        assert!(command_of(1, 0).is_err(), "a kill is never a mode request");
        assert_eq!(command_of_standard(5), Ok(Command::Return));
        assert_eq!(command_of_standard(7), Ok(Command::Land));
        assert!(command_of_standard(0).is_err());
        assert!(command_of_standard(3).is_err(), "cruise is not uquad's");
    }
}
