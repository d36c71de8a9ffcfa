//! Hover path planner, manual set-point commands and the proportional + integral controller.
//!
//! Spec sections 4.3 (gain files and variants), 4.4 (control law, integral rules) with ERRATA
//! 7, 5.1 (hover planner) and 5.2 (manual mode). Units: m, rad, m/s, rad/s; motor speeds rad/s;
//! the control period T_s in µs.

use crate::core::ekf::State;
use crate::core::math::{cos, sin};
use crate::core::model::{GRAVITY_M_S2, MotorLimits, w_hover_rad_s};
use crate::core::path::PathPoint;

/// States the controller works on: the first 12 of the filter's (no accelerometer bias).
pub const N_CONTROLLED: usize = 12;
/// State indices of the 8-state variant: z, ψ, φ, θ, vqz, wqx, wqy, wqz.
pub const REDUCED_STATES: [usize; 8] = [2, 3, 4, 5, 8, 9, 10, 11];

/// Which integrators a controller variant runs, in gain-file column order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Integrators {
    /// ψ, φ, z, θ (the 2012 flights; CTRL_INTEGRAL_ANG).
    PsiPhiZTheta,
    /// x, y, z, θ.
    XYZTheta,
    /// z, θ (the 8-state variant).
    ZTheta,
}

impl Integrators {
    /// State indices of the integrated states, in gain-file column order.
    pub fn states(self) -> &'static [usize] {
        match self {
            Integrators::PsiPhiZTheta => &[3, 4, 2, 5],
            Integrators::XYZTheta => &[0, 1, 2, 5],
            Integrators::ZTheta => &[2, 5],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Integrators::PsiPhiZTheta => "psi,phi,z,theta",
            Integrators::XYZTheta => "x,y,z,theta",
            Integrators::ZTheta => "z,theta",
        }
    }

    pub fn parse(s: &str) -> Option<Integrators> {
        let norm: String = s.chars().filter(|c| !c.is_whitespace()).collect();
        [
            Integrators::PsiPhiZTheta,
            Integrators::XYZTheta,
            Integrators::ZTheta,
        ]
        .into_iter()
        .find(|i| i.name() == norm)
    }
}

/// The largest velocity error flown on the drag's velocity ([`Horizontal::Velocity`]), m/s.
const DRAG_VELOCITY_ERROR_M_S: f64 = 0.5;

/// The horizontal errors as `hold` allows: all with a position; with the velocity only,
/// none for x, y, and the velocity's toward rest (there is no path to fly without a
/// position) within a bound (the drag's velocity reads any steady push as airspeed: the
/// tilt it asks for stays small whatever it reads); none with attitude only.
fn hold_errors(e: &mut [f64; N_CONTROLLED], x_hat: &State, hold: Horizontal) {
    match hold {
        Horizontal::Position => {}
        Horizontal::Velocity => {
            (e[0], e[1]) = (0.0, 0.0);
            for i in [6, 7] {
                e[i] = (-x_hat[i]).clamp(-DRAG_VELOCITY_ERROR_M_S, DRAG_VELOCITY_ERROR_M_S);
            }
        }
        Horizontal::Attitude => {
            for i in HORIZONTAL_STATES {
                e[i] = 0.0;
            }
        }
    }
}

/// What the controller holds horizontally.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Horizontal {
    /// The position and velocity (fixes fused lately).
    Position,
    /// The velocity only: observed without fixes (the drag), the position is not.
    Velocity,
    /// Neither: attitude, altitude and yaw.
    Attitude,
}

/// Update rule of one integrator (ERRATA 7): the step e·T_s is clamped to ±`step_max`, the
/// accumulator to ±`cap`; errors above `threshold` (when set) are not integrated. Also the
/// `control.integral.<state>` configuration table, where `step_max` and `cap` are required
/// (no single default fits every state).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IntegralRule {
    /// Largest change per control step, state unit·s.
    pub step_max: f64,
    /// The accumulator is clamped to ± this, state unit·s.
    pub cap: f64,
    /// Errors larger than this in magnitude are not integrated; absent = no threshold.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold: Option<f64>,
    /// Initial accumulator value, state unit·s.
    #[serde(default)]
    pub seed: f64,
}

impl IntegralRule {
    pub const fn new(step_max: f64, cap: f64, threshold: Option<f64>) -> Self {
        IntegralRule {
            step_max,
            cap,
            threshold,
            seed: 0.0,
        }
    }
}

impl IntegralRule {
    /// One update of accumulator `acc` with error `e` over `t_s` seconds (`ctrl_int`).
    pub fn update(&self, acc: f64, e: f64, t_s: f64) -> f64 {
        if self.threshold.is_some_and(|th| e.abs() > th) {
            return acc;
        }
        let step = (e * t_s).clamp(-self.step_max, self.step_max);
        (acc + step).clamp(-self.cap, self.cap)
    }
}

/// The later version's error limits (`control_limit`): |e_x|, |e_y| ≤ 18 m, |e_z| ≤ 4 m,
/// |e_θ| ≤ 1.05 rad.
pub const ERROR_LIMITS: [(usize, f64); 4] = [(0, 18.0), (1, 18.0), (2, 4.0), (5, 1.05)];

/// The horizontal position and velocity states: x, y, vqx, vqy.
const HORIZONTAL_STATES: [usize; 4] = [0, 1, 6, 7];

/// Gains in the controller's layout: 4 × 12 proportional, 4 × 4 integral (rows = motors).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    pub k_prop: [[f64; N_CONTROLLED]; 4],
    pub k_int: [[f64; 4]; 4],
}

/// The set point: 12 states and the motor speeds around which the controller acts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetPoint {
    pub x: [f64; N_CONTROLLED],
    pub w_rad_s: [f64; 4],
}

/// The controller: gains, integrator rules and state.
#[derive(Debug, Clone)]
pub struct Controller {
    /// 4 × 12, rows = motors (the 8-state gains are placed in their state columns).
    k: [[f64; N_CONTROLLED]; 4],
    /// 4 × n_int, rows = motors, columns in `integrators` order.
    k_int: [[f64; 4]; 4],
    integrators: Integrators,
    rules: [IntegralRule; 4],
    x_int: [f64; 4],
    error_limits: bool,
}

/// Why gains were refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GainError {
    #[error("the proportional gains need {expected} numbers (4 × {cols}), got {got}")]
    KProp {
        expected: usize,
        cols: usize,
        got: usize,
    },
    #[error("the integral gains need {expected} numbers (4 × {cols}), got {got}")]
    KInt {
        expected: usize,
        cols: usize,
        got: usize,
    },
}

impl Controller {
    /// Builds the controller from row-major gain numbers: 4 × 12 (or 4 × 8 with
    /// `reduced = true`) proportional, 4 × n integral with n = the integrator count.
    /// `rules` are per integrator, in the same order. With ψ, φ integrators the x, y, vqx and
    /// vqy columns are forced to zero, as the original did at load time.
    pub fn new(
        k_prop: &[f64],
        k_int: &[f64],
        reduced: bool,
        integrators: Integrators,
        rules: &[IntegralRule],
        error_limits: bool,
    ) -> Result<Controller, GainError> {
        let cols: Vec<usize> = if reduced {
            REDUCED_STATES.to_vec()
        } else {
            (0..N_CONTROLLED).collect()
        };
        if k_prop.len() != 4 * cols.len() {
            return Err(GainError::KProp {
                expected: 4 * cols.len(),
                cols: cols.len(),
                got: k_prop.len(),
            });
        }
        let n_int = integrators.states().len();
        if k_int.len() != 4 * n_int || rules.len() != n_int {
            return Err(GainError::KInt {
                expected: 4 * n_int,
                cols: n_int,
                got: k_int.len(),
            });
        }
        let mut k = [[0.0; N_CONTROLLED]; 4];
        for (m, row) in k.iter_mut().enumerate() {
            for (j, &state) in cols.iter().enumerate() {
                row[state] = k_prop[m * cols.len() + j];
            }
            if integrators == Integrators::PsiPhiZTheta {
                for state in HORIZONTAL_STATES {
                    row[state] = 0.0;
                }
            }
        }
        let mut ki = [[0.0; 4]; 4];
        for (m, row) in ki.iter_mut().enumerate() {
            row[..n_int].copy_from_slice(&k_int[m * n_int..(m + 1) * n_int]);
        }
        let mut r = [IntegralRule::new(0.0, 0.0, None); 4];
        r[..n_int].copy_from_slice(rules);
        let mut x_int = [0.0; 4];
        for (x, rule) in x_int.iter_mut().zip(&r) {
            *x = rule.seed;
        }
        Ok(Controller {
            k,
            k_int: ki,
            integrators,
            rules: r,
            x_int,
            error_limits,
        })
    }

    /// The gains in use.
    pub fn gains(&self) -> Gains {
        Gains {
            k_prop: self.k,
            k_int: self.k_int,
        }
    }

    /// Flies with other gains from the next step on, without a bump: the integrators are
    /// rescaled so the integral action K_int·x_int is what it was (swapping K_int under the
    /// accumulated x_int would step the command at every segment start). When the new K_int
    /// cannot carry it (singular, or an integrator past its cap), the integral gains stay.
    pub fn set_gains(&mut self, g: &Gains) {
        self.k = g.k_prop;
        let n = self.integrators.states().len();
        if n == 4 {
            let old = nalgebra::Matrix4::from_fn(|r, c| self.k_int[r][c]);
            let new = nalgebra::Matrix4::from_fn(|r, c| g.k_int[r][c]);
            let action = old * nalgebra::Vector4::from(self.x_int);
            let rescaled = new.lu().solve(&action).filter(|x| {
                x.iter()
                    .zip(&self.rules)
                    .all(|(v, rule)| v.is_finite() && v.abs() <= rule.cap)
            });
            if let Some(x) = rescaled {
                self.k_int = g.k_int;
                self.x_int = [x[0], x[1], x[2], x[3]];
            }
        }
        if self.integrators == Integrators::PsiPhiZTheta {
            for row in &mut self.k {
                for state in HORIZONTAL_STATES {
                    row[state] = 0.0;
                }
            }
        }
    }

    /// The integrators back to zero (a new flight's control law starts afresh).
    pub fn reset_integrators(&mut self) {
        self.x_int = [0.0; 4];
    }

    /// Integrator states, in gain-file column order.
    pub fn x_int(&self) -> &[f64] {
        &self.x_int[..self.integrators.states().len()]
    }

    pub fn integrators(&self) -> Integrators {
        self.integrators
    }

    /// One control step (spec 4.4): e = sp − x̂; w = sp.w + K·e; integrators updated with
    /// T_s; w += K_int·x_int. Returns the raw controller output (before ramp and saturation).
    pub fn step(&mut self, x_hat: &State, sp: &SetPoint, t_s: f64) -> [f64; 4] {
        self.step_with_hold(x_hat, sp, t_s, Horizontal::Position)
    }

    /// [`Controller::step`], with what is held horizontally. Without a position (no GPS fix
    /// lately: x, y are then the filter's integration and drift without bound) their errors
    /// count as zero, and so do the body velocities' unless the filter still observes them
    /// (the drag, `core::ekf_drag`): the controller holds attitude, altitude and yaw, and
    /// damps the velocity when it can. The x, y integrators keep their values: what they
    /// learnt (a motor's trim) stays applied.
    pub fn step_with_hold(
        &mut self,
        x_hat: &State,
        sp: &SetPoint,
        t_s: f64,
        hold: Horizontal,
    ) -> [f64; 4] {
        let mut e = [0.0; N_CONTROLLED];
        for (i, ei) in e.iter_mut().enumerate() {
            *ei = sp.x[i] - x_hat[i];
        }
        // The gains are designed in the frame of the set point's heading (x forward): the
        // horizontal position error is turned into it. (With ψ, φ integrators the x, y gains
        // are zero and this changes nothing.)
        [e[0], e[1]] = HeadingFrame::of(sp.x[5]).turn([e[0], e[1]]);
        let hold_position = hold == Horizontal::Position;
        hold_errors(&mut e, x_hat, hold);
        if self.error_limits {
            for (i, lim) in ERROR_LIMITS {
                e[i] = e[i].clamp(-lim, lim);
            }
        }
        let mut w = [0.0; 4];
        for (m, wm) in w.iter_mut().enumerate() {
            let mut acc = 0.0;
            for (kj, ej) in self.k[m].iter().zip(&e) {
                acc += kj * ej;
            }
            *wm = sp.w_rad_s[m] + acc;
        }
        // The original updated θ first, then z, then φ/ψ (y/x); each update depends only on
        // its own error, so the order does not change the result.
        let states = self.integrators.states();
        for (k, &state) in states.iter().enumerate().rev() {
            if hold_position || !HORIZONTAL_STATES.contains(&state) {
                self.x_int[k] = self.rules[k].update(self.x_int[k], e[state], t_s);
            }
        }
        for (m, wm) in w.iter_mut().enumerate() {
            let mut acc = 0.0;
            for (kj, xj) in self.k_int[m].iter().zip(&self.x_int).take(states.len()) {
                acc += kj * xj;
            }
            *wm += acc;
        }
        w
    }
}

/// Turns horizontal vectors from the inertial frame into a heading's (x forward, y left).
#[derive(Debug, Clone, Copy)]
struct HeadingFrame {
    sin: f64,
    cos: f64,
}

impl HeadingFrame {
    fn of(yaw_rad: f64) -> Self {
        HeadingFrame {
            sin: sin(yaw_rad),
            cos: cos(yaw_rad),
        }
    }

    fn turn(self, v: [f64; 2]) -> [f64; 2] {
        [
            self.cos * v[0] + self.sin * v[1],
            -self.sin * v[0] + self.cos * v[1],
        ]
    }
}

/// A world-frame vector in the body frame: R(ψ, φ, θ)ᵀ·v (ZYX angles, as the filter's).
pub fn body_from_world(psi: f64, phi: f64, theta: f64, v: [f64; 3]) -> [f64; 3] {
    let r = crate::core::math::rotation_portable(psi, phi, theta);
    std::array::from_fn(|j| r[0][j] * v[0] + r[1][j] * v[1] + r[2][j] * v[2])
}

/// Manual-mode commands (spec 5.2) as typed values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ManualCommand {
    /// ψ set point ± one angle step.
    Roll(Dir),
    /// φ set point ± one angle step.
    Pitch(Dir),
    /// θ set point ± one angle step.
    Yaw(Dir),
    /// z set point ± one altitude step.
    Altitude(Dir),
    /// Mass ± one mass step (then w_hover and w_min follow).
    Weight(Dir),
    /// Mass back to the configured value.
    ResetWeight,
    /// Stop: motors off.
    Quit,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dir {
    Up,
    Down,
}

impl Dir {
    fn sign(self) -> f64 {
        match self {
            Dir::Up => 1.0,
            Dir::Down => -1.0,
        }
    }
}

impl ManualCommand {
    /// The key that gives this command (the inverse of [`ManualCommand::from_key`]).
    pub fn key(self) -> u8 {
        use ManualCommand::*;
        match self {
            Roll(Dir::Up) => b'j',
            Roll(Dir::Down) => b'g',
            Pitch(Dir::Up) => b'y',
            Pitch(Dir::Down) => b'h',
            Yaw(Dir::Up) => b'q',
            Yaw(Dir::Down) => b'w',
            Altitude(Dir::Up) => b'e',
            Altitude(Dir::Down) => b'd',
            Weight(Dir::Up) => b'i',
            Weight(Dir::Down) => b'k',
            ResetWeight => b'0',
            Quit => 27,
        }
    }

    /// The original's keys (spec 5.2): j/g ψ, y/h φ, q/w θ, e/d z, i/k weight, 0 reset, ESC quit.
    pub fn from_key(key: u8) -> Option<ManualCommand> {
        use ManualCommand::*;
        Some(match key {
            b'j' => Roll(Dir::Up),
            b'g' => Roll(Dir::Down),
            b'y' => Pitch(Dir::Up),
            b'h' => Pitch(Dir::Down),
            b'q' => Yaw(Dir::Up),
            b'w' => Yaw(Dir::Down),
            b'e' => Altitude(Dir::Up),
            b'd' => Altitude(Dir::Down),
            b'i' => Weight(Dir::Up),
            b'k' => Weight(Dir::Down),
            b'0' => ResetWeight,
            27 => Quit,
            _ => return None,
        })
    }
}

/// Steps of the manual commands (spec 5.2).
pub const MANUAL_ANGLE_STEP_RAD: f64 = 0.045;
pub const MANUAL_Z_STEP_M: f64 = 0.2;
pub const MANUAL_MASS_STEP_KG: f64 = 0.05;

/// How far manual commands may move the set point (the `control.manual` configuration table).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ManualBounds {
    /// |ψ_sp|, |φ_sp| at most this, rad.
    pub max_tilt_rad: f64,
    /// |θ_sp − θ at calibration| at most this, rad.
    pub max_yaw_offset_rad: f64,
    pub z_min_m: f64,
    pub z_max_m: f64,
    pub mass_min_kg: f64,
    pub mass_max_kg: f64,
}

impl Default for ManualBounds {
    fn default() -> Self {
        ManualBounds {
            max_tilt_rad: 0.27,
            max_yaw_offset_rad: 3.2,
            z_min_m: 0.2,
            z_max_m: 3.0,
            // Lighter than about 0.92 kg, the slowest motor command at w_max = 368 rad/s falls
            // under the ESC start threshold (config::validate refuses it).
            mass_min_kg: 1.0,
            mass_max_kg: 2.2,
        }
    }
}

/// What a manual command did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ManualOutcome {
    /// The set point (or mass) changed.
    Applied,
    /// The command would leave the bounds; nothing changed.
    OutOfBounds,
    /// Stop requested.
    Quit,
}

/// The hover path planner (spec 5.1): a fixed set point, the motor set point from the mass.
#[derive(Debug, Clone)]
pub struct HoverPlanner {
    pub sp: SetPoint,
    theta_home_rad: f64,
    mass_kg: f64,
    default_mass_kg: f64,
    w_max_rad_s: f64,
    bounds: ManualBounds,
}

impl HoverPlanner {
    /// Set point x, y = the GPS start position (0 without GPS), z = `hover_z_m`, θ = θ at
    /// calibration, everything else 0; motors at w_hover(mass).
    pub fn new(
        hover_z_m: f64,
        theta_cal_rad: f64,
        xy_start_m: [f64; 2],
        mass_kg: f64,
        w_max_rad_s: f64,
        bounds: ManualBounds,
    ) -> Self {
        let mut x = [0.0; N_CONTROLLED];
        x[0] = xy_start_m[0];
        x[1] = xy_start_m[1];
        x[2] = hover_z_m;
        x[5] = theta_cal_rad;
        let mut p = HoverPlanner {
            sp: SetPoint {
                x,
                w_rad_s: [0.0; 4],
            },
            theta_home_rad: theta_cal_rad,
            mass_kg,
            default_mass_kg: mass_kg,
            w_max_rad_s,
            bounds,
        };
        p.update_setpoint();
        p
    }

    pub fn mass_kg(&self) -> f64 {
        self.mass_kg
    }

    pub fn limits(&self) -> MotorLimits {
        MotorLimits::new(self.mass_kg, self.w_max_rad_s)
    }

    /// The set point along a path: the position, the heading and its rate; the attitude
    /// whose thrust gives the path's acceleration against gravity; the velocity and rates in
    /// the body frame; the motor speeds whose thrust that is (all four alike).
    pub fn follow(&mut self, p: &PathPoint) {
        let (s, c) = (sin(p.yaw_rad), cos(p.yaw_rad));
        let a = p.acc_m_s2;
        let f_world = [a[0], a[1], a[2] + GRAVITY_M_S2];
        let f_heading = [
            c * f_world[0] + s * f_world[1],
            -s * f_world[0] + c * f_world[1],
            f_world[2],
        ];
        let (psi, phi) = crate::core::trim::attitude_for_force(f_heading);
        let x = &mut self.sp.x;
        x[..3].copy_from_slice(&p.pos_m);
        (x[3], x[4], x[5]) = (psi, phi, p.yaw_rad);
        x[6..9].copy_from_slice(&body_from_world(psi, phi, p.yaw_rad, p.vel_m_s));
        let rate = p.yaw_rate_rad_s;
        let (sps, cps, sph, cph) = (sin(psi), cos(psi), sin(phi), cos(phi));
        x[9..12].copy_from_slice(&[-rate * sph, rate * cph * sps, rate * cph * cps]);
        let f_norm = f_heading.iter().map(|v| v * v).sum::<f64>().sqrt();
        let w = w_hover_rad_s(self.mass_kg * f_norm / GRAVITY_M_S2).min(self.w_max_rad_s);
        self.sp.w_rad_s = [w; 4];
    }

    /// `pp_update_setpoint`: the motor set point follows the current mass.
    pub fn update_setpoint(&mut self) {
        self.sp.w_rad_s = [self.limits().w_hover_rad_s; 4];
    }

    /// The motor set point for a vertical acceleration of `az_m_s2` beyond holding the
    /// weight: the profile's climb and braking flown forward, not left to the integrators
    /// (the original's set point, a hover, is kept bit for bit at 0).
    pub fn accelerate_up(&mut self, az_m_s2: f64) {
        if az_m_s2 != 0.0 && az_m_s2.is_finite() {
            let mass_kg = self.mass_kg * (1.0 + az_m_s2 / GRAVITY_M_S2);
            self.sp.w_rad_s = [w_hover_rad_s(mass_kg.max(0.0)).min(self.w_max_rad_s); 4];
        }
    }

    /// Applies a manual command within the bounds.
    pub fn apply(&mut self, cmd: ManualCommand) -> ManualOutcome {
        let b = self.bounds;
        let within = |v: f64, lo: f64, hi: f64| v >= lo - 1e-12 && v <= hi + 1e-12;
        let (slot, value, ok) = match cmd {
            ManualCommand::Quit => return ManualOutcome::Quit,
            ManualCommand::Roll(d) | ManualCommand::Pitch(d) => {
                let i = if matches!(cmd, ManualCommand::Roll(_)) {
                    3
                } else {
                    4
                };
                let v = self.sp.x[i] + d.sign() * MANUAL_ANGLE_STEP_RAD;
                (Some(i), v, within(v, -b.max_tilt_rad, b.max_tilt_rad))
            }
            ManualCommand::Yaw(d) => {
                let v = self.sp.x[5] + d.sign() * MANUAL_ANGLE_STEP_RAD;
                let off = v - self.theta_home_rad;
                (
                    Some(5),
                    v,
                    within(off, -b.max_yaw_offset_rad, b.max_yaw_offset_rad),
                )
            }
            ManualCommand::Altitude(d) => {
                let v = self.sp.x[2] + d.sign() * MANUAL_Z_STEP_M;
                (Some(2), v, within(v, b.z_min_m, b.z_max_m))
            }
            ManualCommand::Weight(d) => {
                let v = self.mass_kg + d.sign() * MANUAL_MASS_STEP_KG;
                (None, v, within(v, b.mass_min_kg, b.mass_max_kg))
            }
            ManualCommand::ResetWeight => (None, self.default_mass_kg, true),
        };
        if !ok {
            return ManualOutcome::OutOfBounds;
        }
        match slot {
            Some(i) => self.sp.x[i] = value,
            None => {
                self.mass_kg = value;
                self.update_setpoint();
            }
        }
        ManualOutcome::Applied
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rules4() -> [IntegralRule; 4] {
        let r = |step_max, cap, seed| IntegralRule {
            step_max,
            cap,
            threshold: None,
            seed,
        };
        [
            r(1e-3, 1.0, -0.2),
            r(1e-3, 1.0, -0.15),
            r(5e-3, 1.0, 0.0),
            r(7e-3, 2.0, 0.0),
        ]
    }

    #[test]
    fn integral_rule_clamps_and_thresholds() {
        let r = IntegralRule {
            step_max: 1e-3,
            cap: 0.0105,
            threshold: Some(0.26),
            seed: 0.0,
        };
        assert_eq!(r.update(0.0, 0.05, 0.01), 0.0005);
        assert_eq!(r.update(0.0, 0.2, 0.01), 1e-3);
        assert_eq!(r.update(0.0, -0.2, 0.01), -1e-3);
        assert_eq!(r.update(0.01, 0.2, 0.01), 0.0105);
        assert_eq!(r.update(0.004, 0.3, 0.01), 0.004, "above the threshold");
    }

    #[test]
    fn without_position_hold_x_y_and_their_speeds_count_as_zero() {
        // K: 1 on every column; K_int: 1 on every integrator (x, y, z, theta).
        let mut c = Controller::new(
            &[1.0; 48],
            &[1.0; 16],
            false,
            Integrators::XYZTheta,
            &rules4(),
            false,
        )
        .unwrap();
        let sp = SetPoint {
            x: [0.0; 12],
            w_rad_s: [300.0; 4],
        };
        // Estimate: x, y, vqx, vqy and z off by 0.1 each.
        let mut x_hat = State::zeros();
        for i in [0, 1, 2, 6, 7] {
            x_hat[i] = 0.1;
        }
        let held = c
            .clone()
            .step_with_hold(&x_hat, &sp, 0.01, Horizontal::Position);
        let damped = c
            .clone()
            .step_with_hold(&x_hat, &sp, 0.01, Horizontal::Velocity);
        let seeds = c.x_int().to_vec();
        let free = c.step_with_hold(&x_hat, &sp, 0.01, Horizontal::Attitude);
        // Velocity only: z's error and vqx's, vqy's.
        assert!(
            damped
                .iter()
                .zip(&free)
                .all(|(d, f)| (d - f + 0.2).abs() < 1e-9)
        );
        // Held: 5 errors of -0.1; not held: only z's. The integrators: x, y frozen at their
        // seeds, z moved by e·T = -1e-3.
        assert_eq!(c.x_int()[..2], seeds[..2]);
        assert!((c.x_int()[2] - (seeds[2] - 1e-3)).abs() < 1e-15);
        let int_sum: f64 = c.x_int().iter().sum();
        assert!(
            (free[0] - (300.0 - 0.1 + int_sum)).abs() < 1e-12,
            "{free:?}"
        );
        assert!(
            (held[0] - free[0] + 0.4 + 2e-3).abs() < 1e-12,
            "{held:?} {free:?}"
        );
    }

    #[test]
    fn a_gain_swap_keeps_the_integral_action() {
        let k_int: Vec<f64> = (0..16)
            .map(|i| if i % 5 == 0 { 2.0 } else { 0.1 })
            .collect();
        let mut c = Controller::new(
            &[0.0; 48],
            &k_int,
            false,
            Integrators::XYZTheta,
            &rules4(),
            false,
        )
        .unwrap();
        let sp = SetPoint {
            x: [0.0; 12],
            w_rad_s: [300.0; 4],
        };
        let mut x_hat = State::zeros();
        x_hat[0] = 0.3;
        x_hat[2] = -0.2;
        for _ in 0..50 {
            c.step(&x_hat, &sp, 0.01);
        }
        // On the set point (no new integration): the output before and after the swap.
        let before = c.clone().step(&State::zeros(), &sp, 0.01);
        let mut g = c.gains();
        for (r, row) in g.k_int.iter_mut().enumerate() {
            row[r] *= 3.0;
            row[(r + 1) % 4] -= 0.5;
        }
        c.set_gains(&g);
        assert_eq!(c.gains().k_int, g.k_int);
        let after = c.step(&State::zeros(), &sp, 0.01);
        for (a, b) in before.iter().zip(&after) {
            assert!((a - b).abs() < 1e-9, "{before:?} {after:?}");
        }
    }

    #[test]
    fn controller_law_on_a_known_error() {
        // K: only z (column 2) with gain 10, K_int: only z (column 2) with gain 2.
        let mut k = vec![0.0; 48];
        let mut ki = vec![0.0; 16];
        for m in 0..4 {
            k[m * 12 + 2] = 10.0;
            k[m * 12] = 99.0; // x column: zeroed for the psi,phi,z,theta variant
            ki[m * 4 + 2] = 2.0;
        }
        let mut c =
            Controller::new(&k, &ki, false, Integrators::PsiPhiZTheta, &rules4(), false).unwrap();
        assert_eq!(c.x_int(), &[-0.2, -0.15, 0.0, 0.0]);
        let sp = SetPoint {
            x: {
                let mut x = [0.0; 12];
                x[2] = 1.5;
                x
            },
            w_rad_s: [300.0; 4],
        };
        let w = c.step(&State::zeros(), &sp, 0.01);
        // z integrator: e·T = 0.015, clamped to 5e-3.
        assert_eq!(c.x_int()[2], 5e-3);
        assert!((w[0] - (300.0 + 15.0 + 2.0 * 5e-3)).abs() < 1e-12, "{w:?}");
        // The 8-state variant reads 4 × 8 and 4 × 2 numbers.
        let c8 = Controller::new(
            &[1.0; 32],
            &[1.0; 8],
            true,
            Integrators::ZTheta,
            &rules4()[2..],
            false,
        );
        assert!(c8.is_ok());
        assert!(matches!(
            Controller::new(
                &[1.0; 32],
                &[1.0; 16],
                false,
                Integrators::XYZTheta,
                &rules4(),
                false
            ),
            Err(GainError::KProp { expected: 48, .. })
        ));
    }

    #[test]
    fn error_limits_clamp_e() {
        let mut k = vec![0.0; 48];
        for m in 0..4 {
            k[m * 12 + 2] = 1.0;
        }
        let mut c = Controller::new(
            &k,
            &[0.0; 16],
            false,
            Integrators::XYZTheta,
            &rules4(),
            true,
        )
        .unwrap();
        let mut sp = SetPoint {
            x: [0.0; 12],
            w_rad_s: [0.0; 4],
        };
        sp.x[2] = 10.0;
        let w = c.step(&State::zeros(), &sp, 0.01);
        assert_eq!(w[0], 4.0);
    }

    /// The manual keys' bounds the planner tests fly with.
    fn manual_bounds() -> ManualBounds {
        ManualBounds {
            max_tilt_rad: 0.1,
            max_yaw_offset_rad: 0.5,
            z_min_m: 0.5,
            z_max_m: 1.9,
            mass_min_kg: 1.5,
            mass_max_kg: 1.6,
        }
    }

    #[test]
    fn a_climbs_acceleration_is_flown_as_thrust_and_none_keeps_the_hover() {
        let bounds = manual_bounds();
        let mut p = HoverPlanner::new(1.0, 0.0, [0.0, 0.0], 1.55, 368.0, bounds);
        p.update_setpoint();
        let hover = p.sp.w_rad_s;
        p.accelerate_up(0.0);
        assert_eq!(p.sp.w_rad_s, hover, "bit for bit");
        for az_m_s2 in [0.2, -0.2] {
            p.update_setpoint();
            p.accelerate_up(az_m_s2);
            let thrust_n: f64 =
                p.sp.w_rad_s
                    .iter()
                    .map(|&w| crate::core::model::thrust_n(w))
                    .sum();
            let want_n = 1.55 * (GRAVITY_M_S2 + az_m_s2);
            assert!(
                (thrust_n - want_n).abs() < 1e-9,
                "{thrust_n} against {want_n}"
            );
        }
    }

    #[test]
    fn manual_commands_move_within_bounds() {
        let bounds = manual_bounds();
        let mut p = HoverPlanner::new(1.5, 2.0, [0.0, 0.0], 1.55, 368.0, bounds);
        assert_eq!(
            p.apply(ManualCommand::from_key(b'j').unwrap()),
            ManualOutcome::Applied
        );
        assert_eq!(
            p.apply(ManualCommand::Roll(Dir::Up)),
            ManualOutcome::Applied
        );
        assert!((p.sp.x[3] - 0.09).abs() < 1e-12);
        assert_eq!(
            p.apply(ManualCommand::Roll(Dir::Up)),
            ManualOutcome::OutOfBounds
        );
        assert_eq!(
            p.apply(ManualCommand::Altitude(Dir::Up)),
            ManualOutcome::Applied
        );
        assert!((p.sp.x[2] - 1.7).abs() < 1e-12);
        assert_eq!(
            p.apply(ManualCommand::Altitude(Dir::Up)),
            ManualOutcome::Applied
        );
        assert_eq!(
            p.apply(ManualCommand::Altitude(Dir::Up)),
            ManualOutcome::OutOfBounds
        );
        let w0 = p.sp.w_rad_s[0];
        assert_eq!(
            p.apply(ManualCommand::Weight(Dir::Up)),
            ManualOutcome::Applied
        );
        assert!(p.sp.w_rad_s[0] > w0);
        assert_eq!(
            p.apply(ManualCommand::Weight(Dir::Up)),
            ManualOutcome::OutOfBounds
        );
        assert_eq!(p.apply(ManualCommand::ResetWeight), ManualOutcome::Applied);
        assert_eq!(p.sp.w_rad_s[0], w0);
        assert_eq!(
            p.apply(ManualCommand::from_key(27).unwrap()),
            ManualOutcome::Quit
        );
        assert_eq!(ManualCommand::from_key(b'x'), None);
    }
}
