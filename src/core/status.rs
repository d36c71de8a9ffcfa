//! The vehicle's status as those who watch it see it (the ground-station link, the console):
//! the newest step's summary and the health of the parts around it. No spec section: the
//! original had no ground station; its console printed the state in the control loop.
//!
//! One route: the run gathers a [`VehicleStatus`] in one place (`tasks::status`) and both the
//! link and the console's statistics line read it, so they cannot tell different stories.

use crate::core::commander::Mode;
use crate::core::ekf::TestRatios;
use crate::core::gps::LiveFix;
use crate::core::watchdog::TripReason;

/// The pilot's radio as a watcher reads it (made by `core::rc::link`).
pub use crate::core::rc::link::RcStatus;

/// The newest control step, as the controller publishes it each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Live {
    pub step: u32,
    pub x: [f64; 15],
    pub w_rad_s: [f64; 4],
    /// The set point (x, y, z), m.
    pub setpoint_m: [f64; 3],
    /// The commander's mode and the height above the takeoff point it sends the vehicle to, m.
    pub mode: Mode,
    pub height_m: f64,
    /// Steps under the control law so far (the flight ramp is done after 100).
    pub flying_steps: u64,
    /// The estimate's innovation test ratios, and the takeoff point (m), for a ground station.
    pub ratios: TestRatios,
    pub home_m: Option<[f64; 3]>,
    /// The mission item flown or paused at (as loaded).
    pub mission_item: Option<usize>,
}

/// Everything a watcher reads of the running vehicle at one moment.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleStatus {
    /// The commander's mode, as its last change said: ahead of the newest step's (no step
    /// follows an arm during the ESCs' ramp or the calibration, nor a halt's kill).
    pub mode: Mode,
    /// The newest step (none until the first estimate: the IMU still calibrating).
    pub live: Option<Live>,
    /// The newest GPS fix (none without a receiver, or before its first fix).
    pub fix: Option<LiveFix>,
    /// The profile flies with GPS.
    pub gps_used: bool,
    /// IMU frames decoded so far.
    pub imu_frames: u64,
    /// Every ESC acknowledges its writes.
    pub escs_answering: bool,
    /// The watchdog's halt, once it has tripped.
    pub halt: Option<TripReason>,
    /// Why the run folder cannot be written, as last probed (none: it can).
    pub log_problem: Option<String>,
    /// The control thread's CPU time so far, ns (none where it is not measured).
    pub control_cpu_ns: Option<u64>,
    /// Whether an `arm` would pass the pre-arm checks now (none before the first check).
    pub prearm_ok: Option<bool>,
    /// The pilot's radio (none: no receiver configured, or no frame yet).
    pub rc: Option<RcStatus>,
}

impl Default for VehicleStatus {
    fn default() -> Self {
        VehicleStatus {
            mode: Mode::Disarmed,
            live: None,
            fix: None,
            gps_used: false,
            imu_frames: 0,
            escs_answering: false,
            halt: None,
            log_problem: None,
            control_cpu_ns: None,
            prearm_ok: None,
            rc: None,
        }
    }
}
