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

/// The pilot's radio as a watcher reads it (RC_CHANNELS, the console's statistics line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RcStatus {
    /// Channels 1–16 of the newest frame, µs.
    pub channels_us: [u16; crate::core::rc::CHANNELS],
    /// What they read as through the map: roll, pitch, yaw, throttle (each −1…1) and the
    /// switches; the mode switch's selection.
    pub sticks: [f64; 4],
    pub arm: bool,
    pub kill: bool,
    pub mode: Option<crate::core::rc::link::RcMode>,
    /// The receiver's link statistics (CRSF): packets received of the last 100, %, and the
    /// signal strength, dBm.
    pub link_quality_pct: Option<u8>,
    pub rssi_dbm: Option<i16>,
    /// The receiver says its transmitter is gone.
    pub lost: bool,
}

impl RcStatus {
    /// The console's words for it: ` rc=[ROLL,PITCH,YAW,THROTTLE] arm=on|off kill=on|off
    /// mode=NAME` and the link's `lq=PCT rssi=DBM` where the receiver measures them;
    /// ` rc=lost` once its receiver is in failsafe.
    pub fn words(&self) -> String {
        if self.lost {
            return " rc=lost".into();
        }
        let on = |b: bool| if b { "on" } else { "off" };
        let [r, p, y, t] = self.sticks;
        let mut s = format!(
            " rc=[{r:+.2},{p:+.2},{y:+.2},{t:+.2}] arm={} kill={} mode={}",
            on(self.arm),
            on(self.kill),
            self.mode.map_or("-", |m| m.name())
        );
        if let (Some(lq), Some(rssi)) = (self.link_quality_pct, self.rssi_dbm) {
            s += &format!(" lq={lq}% rssi={rssi}dBm");
        }
        s
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::rc::link::RcMode;

    #[test]
    fn the_console_says_the_sticks_switches_and_link() {
        let mut rc = RcStatus {
            channels_us: [1500; crate::core::rc::CHANNELS],
            sticks: [0.0, 0.5, -0.25, -1.0],
            arm: true,
            kill: false,
            mode: Some(RcMode::Position),
            link_quality_pct: Some(98),
            rssi_dbm: Some(-61),
            lost: false,
        };
        assert_eq!(
            rc.words(),
            " rc=[+0.00,+0.50,-0.25,-1.00] arm=on kill=off mode=position lq=98% rssi=-61dBm"
        );
        rc.lost = true;
        assert_eq!(rc.words(), " rc=lost");
    }
}
