//! The hover window, one definition for both ways of simulating: it opens `sim.settle_s` after
//! the flight ramp ends and measures the true state against the controller's set point, one
//! sample per IMU period while the motors are under flight commands. Also the progress line
//! both ways print.

use super::physics::Plant;
use crate::core::commander::{ClimbTrace, DescentTrace, Figures, Mode, Touchdown};
use serde::Serialize;

/// The hover quality of a simulated flight: the true state against the set point.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct HoverStats {
    #[serde(rename = "hover_samples")]
    pub samples: u64,
    pub alt_rms_m: f64,
    pub roll_rms_rad: f64,
    pub pitch_rms_rad: f64,
    /// Largest |altitude - set point| in the window, m.
    pub alt_max_err_m: f64,
    /// Largest distance from the set point (x, y and z) in the window, m.
    pub pos_max_err_m: f64,
    /// Simulated time the window started, s.
    #[serde(rename = "hover_window_start_s")]
    pub window_start_s: f64,
}

/// The window and the sums of squares behind [`HoverStats`].
#[derive(Debug, Clone, Copy, Default)]
pub struct HoverWindow {
    settle_us: i64,
    /// When the flight ramp was first seen done.
    ramp_end_us: Option<i64>,
    stats: HoverStats,
    se_z: f64,
    se_roll: f64,
    se_pitch: f64,
}

/// The flight's side of one hover sample: whether its flight ramp is done, its set point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightView {
    pub ramp_done: bool,
    pub setpoint_m: [f64; 3],
    /// Motors under flight commands (false once halted).
    pub flying: bool,
}

/// The plant's side: true position (m), roll and pitch (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueState {
    pub pos_m: [f64; 3],
    pub roll_rad: f64,
    pub pitch_rad: f64,
}

impl TrueState {
    pub fn of(plant: &Plant) -> Self {
        let e = plant.euler_rad();
        TrueState {
            pos_m: plant.position_m(),
            roll_rad: e[0],
            pitch_rad: e[1],
        }
    }
}

/// The takeoff and landing of the true vehicle: the climb's overshoot, and the speed at which
/// it met the ground while landing (the fastest descent of the second before the contact).
#[derive(Debug, Clone, Default)]
pub struct CycleTrace {
    /// Where the takeoff started (x, y), m.
    home_xy_m: Option<[f64; 2]>,
    climb: ClimbTrace,
    descent: DescentTrace,
    was_on_ground: bool,
    touchdown: Option<Touchdown>,
    /// The mode at the last sample; the run's earlier flights' figures; armings seen.
    last_mode: Option<Mode>,
    past: Vec<Figures>,
    flights: u32,
}

impl CycleTrace {
    /// One IMU period: the mode, the height the commander sends the vehicle to above the
    /// takeoff point, and the truth.
    pub fn sample(&mut self, t_us: i64, mode: Mode, height_m: f64, plant: &Plant) {
        let p = plant.position_m();
        let vz = plant.velocity_m_s()[2];
        let before = self.last_mode.replace(mode);
        if mode == Mode::Armed && before != Some(Mode::Armed) {
            self.begin_flight();
        }
        if mode == Mode::Takeoff && self.home_xy_m.is_none() {
            self.home_xy_m = Some([p[0], p[1]]);
            self.climb.begin(p[2], height_m);
        }
        self.climb.sample(mode, p[2], vz);
        let contact = plant.on_ground && !self.was_on_ground;
        if mode == Mode::Land && contact && self.touchdown.is_none() {
            let home = self.home_xy_m.unwrap_or_default();
            self.touchdown = Some(Touchdown {
                t_us,
                v_m_s: self.descent.peak_m_s(),
                from_takeoff_m: (p[0] - home[0]).hypot(p[1] - home[1]),
            });
        }
        self.descent.sample(t_us, vz);
        self.was_on_ground = plant.on_ground;
    }

    /// An arming: the run's next flight (an earlier one keeps its figures).
    fn begin_flight(&mut self) {
        if self.flights > 0 {
            self.past.push(self.figures());
            self.home_xy_m = None;
            self.climb = ClimbTrace::default();
            self.touchdown = None;
        }
        self.flights += 1;
    }

    /// The figures of the flight flown last for the report; the touchdown's time is the
    /// contact's.
    pub fn figures(&self) -> Figures {
        Figures {
            takeoff: self.climb.takeoff(),
            touchdown: self.touchdown,
        }
    }

    /// Every flight's figures, one per arming in order.
    pub fn flight_figures(&self) -> Vec<Figures> {
        let mut all = self.past.clone();
        // A flight that started armed (`commander.start = "flying"`) may never be sampled
        // in `armed`: its figures still count.
        if self.flights > 0 || self.figures() != Figures::default() {
            all.push(self.figures());
        }
        all
    }
}

/// The progress line both ways of simulating print every 5 simulated seconds.
pub fn progress_line(t_us: i64, plant: &Plant, phase: &str, steps: u64) -> String {
    let e = plant.euler_rad();
    format!(
        "sim {:5.1} s  z {:6.3} m  roll {:+.3} pitch {:+.3} rad  {phase}  steps {steps}",
        t_us as f64 / 1e6,
        plant.position_m()[2],
        e[0],
        e[1],
    )
}

impl HoverWindow {
    pub fn new(settle_s: f64) -> Self {
        HoverWindow {
            settle_us: (settle_s * 1e6) as i64,
            ..HoverWindow::default()
        }
    }

    /// One IMU period at simulated time `t_us`.
    pub fn sample(&mut self, t_us: i64, flight: FlightView, truth: TrueState) {
        if flight.ramp_done && self.ramp_end_us.is_none() {
            self.ramp_end_us = Some(t_us);
        }
        let open = self
            .ramp_end_us
            .is_some_and(|end| t_us >= end + self.settle_us);
        if !open || !flight.flying {
            return;
        }
        let err_m: [f64; 3] = std::array::from_fn(|i| truth.pos_m[i] - flight.setpoint_m[i]);
        self.add(t_us as f64 / 1e6, err_m, truth.roll_rad, truth.pitch_rad);
    }

    fn add(&mut self, t_s: f64, pos_err_m: [f64; 3], roll_rad: f64, pitch_rad: f64) {
        let alt_err_m = pos_err_m[2];
        if self.stats.samples == 0 {
            self.stats.window_start_s = t_s;
        }
        self.stats.samples += 1;
        self.se_z += alt_err_m * alt_err_m;
        self.se_roll += roll_rad * roll_rad;
        self.se_pitch += pitch_rad * pitch_rad;
        self.stats.alt_max_err_m = self.stats.alt_max_err_m.max(alt_err_m.abs());
        let dist_m = pos_err_m.iter().map(|e| e * e).sum::<f64>().sqrt();
        self.stats.pos_max_err_m = self.stats.pos_max_err_m.max(dist_m);
    }

    pub fn stats(&self) -> HoverStats {
        let mut h = self.stats;
        if h.samples > 0 {
            let n = h.samples as f64;
            h.alt_rms_m = (self.se_z / n).sqrt();
            h.roll_rms_rad = (self.se_roll / n).sqrt();
            h.pitch_rms_rad = (self.se_pitch / n).sqrt();
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opens_settle_after_the_ramp_and_measures_against_the_set_point() {
        let mut w = HoverWindow::new(1.0);
        let truth = TrueState {
            pos_m: [0.0, 0.0, 1.1],
            roll_rad: 0.01,
            pitch_rad: 0.0,
        };
        let mut flight = FlightView {
            ramp_done: false,
            setpoint_m: [0.0, 0.0, 1.0],
            flying: true,
        };
        w.sample(10_000, flight, truth);
        flight.ramp_done = true;
        w.sample(20_000, flight, truth);
        w.sample(1_010_000, flight, truth);
        assert_eq!(w.stats().samples, 0, "not before settle_s after the ramp");
        w.sample(1_020_000, flight, truth);
        flight.flying = false;
        w.sample(1_030_000, flight, truth);
        let s = w.stats();
        assert_eq!(s.samples, 1);
        assert!((s.alt_rms_m - 0.1).abs() < 1e-12 && (s.pos_max_err_m - 0.1).abs() < 1e-12);
        assert_eq!(s.window_start_s, 1.02);
        assert!((s.roll_rms_rad - 0.01).abs() < 1e-15);
    }
}
