//! What the true vehicle did that the safety campaign judges (`uquad campaign`): every contact
//! with the ground after flying and its speed, the longest time the motors ran on the ground
//! outside a takeoff once the start-up was over, the farthest it went from where it started,
//! whether a halt struck in the air, and — once a run has ended with the vehicle still up —
//! the fall to the ground that follows with the motors stopped.

use crate::core::commander::Mode;
use crate::sim::physics::Plant;

/// A contact with the ground after flying.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Contact {
    pub t_s: f64,
    /// Downward speed just before the contact, m/s.
    pub v_m_s: f64,
    /// The commander's mode at the contact (`fall` for the fall after the run ended).
    pub mode: &'static str,
}

/// The campaign's figures of one run.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SafetyFigures {
    pub contacts: Vec<Contact>,
    /// The longest stretch with the motors turning on the ground, outside a takeoff, once the
    /// start-up was over (the ESCs' ramp, and a calibration after it), s.
    pub ground_run_max_s: f64,
    /// The farthest horizontal distance from the starting point, m.
    pub max_from_start_m: f64,
    /// The vehicle was in the air when the halt struck.
    pub halt_in_air: bool,
    /// The vehicle was in the air when the run ended (before its fall).
    pub ended_in_air: bool,
}

/// The per-frame trace behind [`SafetyFigures`].
#[derive(Debug, Clone, Default)]
pub struct SafetyTrace {
    start_xy_m: Option<[f64; 2]>,
    flown: bool,
    was_on_ground: bool,
    ground_run_from_us: Option<i64>,
    figures: SafetyFigures,
}

/// The motors turn when any of them is told more than this, rad/s.
const TURNING_RAD_S: f64 = 1.0;

impl SafetyTrace {
    /// One IMU period: the true vehicle, the commander's mode, and whether the start-up is over.
    pub fn sample(&mut self, t_us: i64, plant: &mut Plant, mode: Mode, started_up: bool) {
        let p = plant.position_m();
        let start = *self.start_xy_m.get_or_insert([p[0], p[1]]);
        let from_start_m = (p[0] - start[0]).hypot(p[1] - start[1]);
        self.figures.max_from_start_m = self.figures.max_from_start_m.max(from_start_m);
        self.contact(t_us, plant, mode.name());
        let turning = plant.w_cmd_rad_s.iter().any(|w| *w > TURNING_RAD_S);
        let idling = plant.on_ground && turning && started_up && mode != Mode::Takeoff;
        match (idling, self.ground_run_from_us) {
            (true, None) => self.ground_run_from_us = Some(t_us),
            (true, Some(from)) => {
                let s = (t_us - from) as f64 / 1e6;
                self.figures.ground_run_max_s = self.figures.ground_run_max_s.max(s);
            }
            (false, _) => self.ground_run_from_us = None,
        }
    }

    /// A frame that finds the vehicle on the ground after one that did not is a contact, at
    /// the hardest hit since the last frame (the plant's own step: a touchdown that hops
    /// before the frame is judged by its first hit, not by the hop's).
    fn contact(&mut self, t_us: i64, plant: &mut Plant, mode: &'static str) {
        if !plant.on_ground {
            self.flown = true;
        }
        let hit_m_s = plant.take_touchdown_m_s();
        if plant.on_ground && !self.was_on_ground && self.flown {
            self.figures.contacts.push(Contact {
                t_s: t_us as f64 / 1e6,
                v_m_s: hit_m_s,
                mode,
            });
        }
        self.was_on_ground = plant.on_ground;
    }

    /// A halt struck now.
    pub fn halt(&mut self, plant: &Plant) {
        self.figures.halt_in_air |= !plant.on_ground;
    }

    /// The run is over: a vehicle still in the air falls with its motors stopped (at most 60
    /// simulated seconds, in steps of `step_us`) and its contact is recorded as `fall`.
    pub fn finish(mut self, plant: &mut Plant, step_us: i64) -> SafetyFigures {
        self.figures.ended_in_air = !plant.on_ground;
        plant.w_cmd_rad_s = [0.0; 4];
        let mut t_us = plant.t_us;
        let until_us = t_us + 60_000_000;
        while !plant.on_ground && t_us < until_us {
            plant.step(step_us);
            t_us += step_us;
            self.contact(t_us, plant, "fall");
        }
        self.figures
    }
}
