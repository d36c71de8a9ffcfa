//! Why the commander refuses a command (spec: none; the original took every key). Each
//! reason is a variant, and its words — what err.log, mode.log, the console and a ground
//! station show after "`command` refused: " — are written once, in its `Display`.

use super::{Failsafe, Mode};
use crate::core::ekf::TestRatios;
use std::fmt;

/// Why a command is refused.
#[derive(Debug, Clone, PartialEq)]
pub enum Refusal {
    /// A pre-arm check failed: its verdict's words (the facts the driver observed, the
    /// calibration's plausibility, or a replay's record of them).
    PreArm(String),
    /// A takeoff's or a hold's height outside the allowed heights, m.
    HeightOutside { z_m: f64, min_m: f64, max_m: f64 },
    /// A hold's point outside the fence, m from the takeoff point.
    OutsideFence { r_m: f64, radius_m: f64 },
    /// Killed: only a restart flies again.
    Killed,
    /// The vehicle is in this mode already.
    Already(Mode),
    /// Landed once, in a profile that calibrates after arming: only a restart flies again.
    Landed,
    /// A hold point moved while not holding.
    MoveNeedsHold(Mode),
    /// A calibration asked for in a profile that calibrates after arming (it does then).
    CalibratesAfterArm,
    /// A calibration asked for while not disarmed.
    CalibrateNeedsDisarmed(Mode),
    /// In the air in this mode: land first, or kill.
    InTheAir(Mode),
    /// A failsafe acts and its cause persists (none named: its kind was not found).
    FailsafeActing(Option<Failsafe>),
    /// A takeoff from a mode other than armed.
    TakeoffNeedsArmed(Mode),
    /// Armed, the ESCs' start-up ramp still running.
    EscRampRunning,
    /// A pause with no mission flying.
    NoMissionFlying(Mode),
    /// A return during a landing.
    LandingGoesOn,
    /// A hold "here" on the ground, under `control.manual.z_min_m` above the takeoff point.
    HoldOnGround { mode: Mode, z_min_m: f64 },
    /// Hold, land or return while not in the air.
    NotInTheAir(Mode),
    /// No estimate yet: the IMU calibration is not done.
    EstimatorNotRunning,
    /// The gyro's counts repeat.
    GyroStuck,
    /// The estimator's test ratios outside the gate.
    EstimatorOutsideGate(TestRatios),
    /// No GPS fix within `control.gps_hold_timeout_s`.
    NoFix { timeout_s: f64 },
    /// `start` with no mission loaded.
    NoMission,
    /// `start` from the ground of a mission that does not begin with a takeoff.
    MissionWithoutTakeoff,
    /// `start` from a mode other than armed or hold.
    StartNeedsArmedOrHold(Mode),
    /// A path with no fix fused lately.
    NoRecentFix,
    /// `resume` with no paused mission.
    NoPausedMission(Mode),
    /// A new mission while one is flown.
    MissionBeingFlown(Mode),
    /// Not applied within `commander.input_expiry_s` of its arrival.
    Expired { input_expiry_s: f64 },
    /// A motor test while not disarmed.
    MotorTestNeedsDisarmed(Mode),
    /// A motor test's motor, throttle or time out of its bounds.
    MotorTestOutOfBounds {
        motor: u8,
        throttle_pct: f64,
        duration_s: f64,
    },
    /// A motor test runs (of this motor, 1-based) until this time of the run, s.
    MotorTestRunning { motor: u8, until_s: f64 },
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use Refusal::*;
        match self {
            PreArm(why) => f.write_str(why),
            HeightOutside { z_m, min_m, max_m } => write!(
                f,
                "height {z_m} m outside {min_m}..{max_m} m (control.manual.z_min_m, z_max_m, \
                 fence.alt_max_m)"
            ),
            OutsideFence { r_m, radius_m } => write!(
                f,
                "{r_m:.1} m from the takeoff point: outside fence.radius_m = {radius_m} m"
            ),
            Killed => f.write_str("killed: restart uquad to fly again"),
            Already(m) => write!(f, "already {}", m.name()),
            MoveNeedsHold(m) => write!(f, "{}: a hold point moves only in hold", m.name()),
            CalibratesAfterArm => f.write_str(
                "this profile calibrates the IMU after arming (imu.calibrate = \"after-arm\")",
            ),
            CalibrateNeedsDisarmed(m) => {
                write!(f, "{}: the IMU calibrates at rest, disarmed", m.name())
            }
            Landed => f.write_str(
                "landed: one flight per run in this profile (its IMU calibrates after arming, or it starts flying): restart uquad to fly again",
            ),
            InTheAir(m) => write!(f, "in the air ({}): land first, or kill", m.name()),
            FailsafeActing(k) => write!(
                f,
                "failsafe {} is acting and its cause persists",
                k.map_or("?", |k| k.name())
            ),
            TakeoffNeedsArmed(m) => write!(f, "{}: takeoff needs armed", m.name()),
            EscRampRunning => f.write_str("armed: the ESCs' start-up ramp is not done yet"),
            NoMissionFlying(m) => write!(f, "{}: no mission flying", m.name()),
            LandingGoesOn => f.write_str("landing: a landing goes on"),
            HoldOnGround { mode, z_min_m } => write!(
                f,
                "{}: on the ground (under control.manual.z_min_m = {z_min_m} m above the \
                 takeoff point); hold X Y Z, land, or disarm",
                mode.name()
            ),
            NotInTheAir(m) => write!(f, "{}: not in the air", m.name()),
            EstimatorNotRunning => {
                f.write_str("estimator: not running yet (the IMU calibration is not done)")
            }
            GyroStuck => f.write_str("estimator: gyro stuck (its counts repeat)"),
            EstimatorOutsideGate(r) => write!(
                f,
                "estimator: innovation test ratios outside the gate (attitude {:.2}, altitude \
                 {:.2}, gps {:?})",
                r.attitude, r.altitude, r.gps
            ),
            NoFix { timeout_s } => write!(
                f,
                "gps: no fix within control.gps_hold_timeout_s = {timeout_s} s"
            ),
            NoMission => f.write_str(
                "no mission loaded (uquad sim --mission FILE, uquad fly --mission FILE)",
            ),
            MissionWithoutTakeoff => {
                f.write_str("the mission does not begin with a takeoff: take off, then start")
            }
            StartNeedsArmedOrHold(m) => {
                write!(
                    f,
                    "{}: start needs armed (on the ground), hold or position",
                    m.name()
                )
            }
            NoRecentFix => {
                f.write_str("gps: no fix lately (position hold is off): a path cannot be flown")
            }
            NoPausedMission(m) => write!(f, "{}: no paused mission", m.name()),
            MissionBeingFlown(m) => {
                write!(f, "{}: a mission is being flown: pause it first", m.name())
            }
            MotorTestNeedsDisarmed(m) => {
                write!(f, "{}: a motor test runs only disarmed, on the ground", m.name())
            }
            MotorTestOutOfBounds {
                motor,
                throttle_pct,
                duration_s,
            } => write!(
                f,
                "motor {motor} at {throttle_pct} % for {duration_s} s: a motor test takes \
                 motor 1 to 4, a throttle above 0 up to {} % (0 stops a test) and a time above \
                 0 up to {} s",
                crate::core::esc::MOTOR_TEST_MAX_PCT,
                crate::core::esc::MOTOR_TEST_MAX_S
            ),
            MotorTestRunning { motor, until_s } => write!(
                f,
                "a motor test of motor {motor} runs until {until_s:.1} s: wait, or end it (disarm, \
                 or a throttle of 0)"
            ),
            Expired { input_expiry_s } => write!(
                f,
                "not applied within commander.input_expiry_s = {input_expiry_s} s of its \
                 arrival: the flight was not taking inputs (no IMU frames)"
            ),
        }
    }
}
