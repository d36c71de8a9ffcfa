//! Rigid-body physics of the uQuad (spec 3.2, 3.3 and 4.1): the same equations the filter
//! models — body-frame velocities and rates, thrust and drag-torque polynomials, rotor inertia —
//! with the corrected z kinematics, plus what the filter does not model: first-order motor lag,
//! linear air drag with optional wind, and the ground. Integrated with fixed steps (1 kHz or
//! more). Units: m, rad, m/s, rad/s, N, s.

use crate::core::ekf::{State, idx, process};
use crate::core::model::{F_B1, F_B2, GRAVITY_M_S2, thrust_n};

/// Physical parameters beyond the model constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantParams {
    pub mass_kg: f64,
    /// Motor time constant, s.
    pub motor_tau_s: f64,
    /// Linear air drag, N per m/s of airspeed.
    pub drag_n_per_m_s: f64,
    /// Steady wind (inertial x north, y west, z up), m/s.
    pub wind_m_s: [f64; 3],
}

/// How fast the ground levels a vehicle resting on it, s (its legs settling), up to this
/// tilt, rad.
const GROUND_LEVEL_TAU_S: f64 = 0.05;
const GROUND_LEVEL_MAX_RAD: f64 = 0.3;

/// The true state of the vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct Plant {
    pub params: PlantParams,
    /// x, y, z, ψ, φ, θ, body velocities, body rates (the filter's first 12 states; the last
    /// three, accelerometer bias, stay 0 here).
    pub x: State,
    /// Motor speeds, rad/s.
    pub w_rad_s: [f64; 4],
    /// Commanded motor speeds, rad/s.
    pub w_cmd_rad_s: [f64; 4],
    /// Simulated time, µs.
    pub t_us: i64,
    /// Specific force in the body frame of the last step (what an accelerometer reads), m/s².
    pub specific_force_m_s2: [f64; 3],
    pub on_ground: bool,
    /// Thrust of each motor relative to the model (a damaged propeller: below 1).
    pub thrust_scale: [f64; 4],
    /// An outside push (a gust), inertial frame, N.
    pub push_n: [f64; 3],
    /// The ground's stop of a touchdown still being felt: its deceleration (inertial frame,
    /// m/s²) and how long it lasts yet, µs.
    stop_m_s2: [f64; 3],
    stop_left_us: i64,
    /// The hardest touchdown's downward speed since [`Plant::take_touchdown_m_s`] last
    /// looked, m/s (measured at the physics' step: the hops of one touchdown between two
    /// frames do not hide its first hit).
    touchdown_m_s: f64,
}

/// A touchdown's stop lasts this long (the legs' give), µs: the accelerometer feels the
/// whole change of speed, as a real one feels the shock (a 1 m/s touchdown: 5 g for 20 ms).
const STOP_US: i64 = 20_000;

pub use crate::core::math::rotation;

fn mul(r: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

fn mul_t(r: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[0][i] * v[0] + r[1][i] * v[1] + r[2][i] * v[2])
}

impl Plant {
    /// At rest on the ground, level, facing `yaw_rad`.
    pub fn new(params: PlantParams, yaw_rad: f64) -> Self {
        let mut x = State::zeros();
        x[idx::THETA] = yaw_rad;
        Plant {
            params,
            x,
            w_rad_s: [0.0; 4],
            w_cmd_rad_s: [0.0; 4],
            t_us: 0,
            specific_force_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            on_ground: true,
            thrust_scale: [1.0; 4],
            push_n: [0.0; 3],
            stop_m_s2: [0.0; 3],
            stop_left_us: 0,
            touchdown_m_s: 0.0,
        }
    }

    /// Advances by `dt_us`.
    pub fn step(&mut self, dt_us: i64) {
        let dt = dt_us as f64 * 1e-6;
        let p = self.params;
        // Motors: first-order lag toward the command.
        let a = (dt / p.motor_tau_s).min(1.0);
        for (w, c) in self.w_rad_s.iter_mut().zip(self.w_cmd_rad_s) {
            *w += a * (c - *w);
        }
        let r = rotation(self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]);
        let v_body = [self.x[idx::VQX], self.x[idx::VQY], self.x[idx::VQZ]];
        let v_in = mul(&r, &v_body);
        // Air drag on the airspeed, as a body-frame acceleration.
        let air: [f64; 3] = std::array::from_fn(|i| p.wind_m_s[i] - v_in[i]);
        let drag_in: [f64; 3] =
            std::array::from_fn(|i| (p.drag_n_per_m_s * air[i] + self.push_n[i]) / p.mass_kg);
        let drag_body = mul_t(&r, &drag_in);
        // A motor with a scaled thrust acts as the model's motor at the speed giving that thrust.
        let w_eff: [f64; 4] = std::array::from_fn(|i| {
            let w = self.w_rad_s[i].max(0.0);
            let k = self.thrust_scale[i];
            if k == 1.0 {
                w
            } else {
                let t = k * thrust_n(w);
                (-F_B2 + (F_B2 * F_B2 + 4.0 * F_B1 * t.max(0.0)).sqrt()) / (2.0 * F_B1)
            }
        });
        let thrust: f64 = w_eff.iter().map(|&w| thrust_n(w)).sum();
        // The filter's model is the rigid body; its bias slots carry the drag here.
        let mut ext = self.x;
        ext[idx::BAX] = drag_body[0];
        ext[idx::BAY] = drag_body[1];
        ext[idx::BAZ] = drag_body[2];
        let mut next = process(&ext, &w_eff, dt, p.mass_kg, false);
        next[idx::BAX] = 0.0;
        next[idx::BAY] = 0.0;
        next[idx::BAZ] = 0.0;
        // The ground: it holds the vehicle up and level until the thrust lifts it, and stops it
        // when it comes down.
        let lift = thrust / p.mass_kg > GRAVITY_M_S2;
        let pinned = (self.on_ground && !lift) || (!self.on_ground && next[idx::Z] < 0.0);
        if pinned {
            for i in [idx::Z, idx::VQX, idx::VQY, idx::VQZ] {
                next[i] = 0.0;
            }
            // Roll and pitch settle onto the legs at a rate the gyros feel (a vehicle that
            // tipped on a weak motor's side and came down was levelled within one step, unseen
            // by the gyros: its estimate stayed tilted by the tip, 0.12 rad). A vehicle further
            // over, on its side, is beyond this ground's model: set upright at once, as before.
            let (psi, phi) = (self.x[idx::PSI], self.x[idx::PHI]);
            let settling = psi.abs() <= GROUND_LEVEL_MAX_RAD && phi.abs() <= GROUND_LEVEL_MAX_RAD;
            let (psi_dot, phi_dot) = if settling {
                (-psi / GROUND_LEVEL_TAU_S, -phi / GROUND_LEVEL_TAU_S)
            } else {
                (0.0, 0.0)
            };
            // The body rates whose Euler rates these are, the yaw held (the model's
            // kinematics: ψ' = wx + tan φ (wz cos ψ + wy sin ψ), φ' = wy cos ψ − wz sin ψ).
            next[idx::WQX] = psi_dot;
            next[idx::WQY] = phi_dot * psi.cos();
            next[idx::WQZ] = -phi_dot * psi.sin();
            next[idx::PSI] = if settling { psi + psi_dot * dt } else { 0.0 };
            next[idx::PHI] = if settling { phi + phi_dot * dt } else { 0.0 };
            next[idx::X] = self.x[idx::X];
            next[idx::Y] = self.x[idx::Y];
            next[idx::THETA] = self.x[idx::THETA];
            // A touchdown; the bounces of one (the thrust near the weight lifts the vehicle
            // off for a step) are within its stop.
            if !self.on_ground {
                self.touchdown_m_s = self.touchdown_m_s.max(-v_in[2]);
            }
            if !self.on_ground && self.stop_left_us <= 0 {
                self.stop_m_s2 = v_in.map(|v| -v / (STOP_US as f64 * 1e-6));
                self.stop_left_us = STOP_US;
            }
            self.on_ground = true;
        } else {
            if self.on_ground {
                // Lifting off the legs: their settling's rate stays on the ground.
                next[idx::WQX] = 0.0;
                next[idx::WQY] = 0.0;
                next[idx::WQZ] = 0.0;
            }
            self.on_ground = false;
        }
        // Specific force: thrust and drag; on the ground the ground's push instead.
        self.specific_force_m_s2 = if self.on_ground {
            mul_t(&r, &[0.0, 0.0, GRAVITY_M_S2])
        } else {
            [
                drag_body[0],
                drag_body[1],
                thrust / p.mass_kg + drag_body[2],
            ]
        };
        // The stop is felt for its whole length, also when the thrust lifts the vehicle
        // off again meanwhile (a bounce).
        if self.stop_left_us > 0 {
            self.stop_left_us -= dt_us;
            let stop_body = mul_t(&r, &self.stop_m_s2);
            for (f, s) in self.specific_force_m_s2.iter_mut().zip(stop_body) {
                *f += s;
            }
        }
        self.x = next;
        self.t_us += dt_us;
    }

    /// The hardest touchdown's speed since the last call, m/s (0 when none).
    pub fn take_touchdown_m_s(&mut self) -> f64 {
        std::mem::take(&mut self.touchdown_m_s)
    }

    /// Velocity in the inertial frame (x north, y west, z up), m/s.
    pub fn velocity_m_s(&self) -> [f64; 3] {
        let r = rotation(self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]);
        mul(&r, &[self.x[idx::VQX], self.x[idx::VQY], self.x[idx::VQZ]])
    }

    /// Position (x north, y west, z up), m.
    pub fn position_m(&self) -> [f64; 3] {
        [self.x[idx::X], self.x[idx::Y], self.x[idx::Z]]
    }

    /// Body rates, rad/s.
    pub fn rates_rad_s(&self) -> [f64; 3] {
        [self.x[idx::WQX], self.x[idx::WQY], self.x[idx::WQZ]]
    }

    /// Roll, pitch, yaw, rad.
    pub fn euler_rad(&self) -> [f64; 3] {
        [self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]]
    }

    /// A vector given in the inertial frame, seen in the body frame.
    pub fn to_body(&self, v: &[f64; 3]) -> [f64; 3] {
        let e = self.euler_rad();
        mul_t(&rotation(e[0], e[1], e[2]), v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::model::w_hover_rad_s;

    fn params() -> PlantParams {
        PlantParams {
            mass_kg: 1.55,
            motor_tau_s: 0.03,
            drag_n_per_m_s: 0.1,
            wind_m_s: [0.0; 3],
        }
    }

    #[test]
    fn rests_on_the_ground_reading_gravity() {
        let mut p = Plant::new(params(), 0.3);
        for _ in 0..1000 {
            p.step(1000);
        }
        assert!(p.on_ground);
        assert_eq!(p.position_m(), [0.0; 3]);
        assert!((p.specific_force_m_s2[2] - GRAVITY_M_S2).abs() < 1e-12);
    }

    #[test]
    fn the_ground_levels_a_tipped_vehicle_at_a_rate_the_gyros_feel() {
        // Came down 0.12 rad over on one side (a weak motor's tip at the spool-up).
        let mut p = Plant::new(params(), 0.0);
        p.x[idx::PHI] = 0.12;
        p.step(1000);
        let w = p.x[idx::WQY];
        assert!((w + 0.12 / GROUND_LEVEL_TAU_S).abs() < 0.1, "{w}");
        for _ in 0..300 {
            p.step(1000);
        }
        assert!(
            p.x[idx::PHI].abs() < 0.001 && p.x[idx::WQY].abs() < 0.1,
            "{:?}",
            p.x
        );
        // On its side: beyond the legs' settling, set upright at once, as this ground did.
        p.x[idx::PSI] = 1.2;
        p.step(1000);
        assert_eq!((p.x[idx::PSI], p.x[idx::WQX]), (0.0, 0.0));
    }

    #[test]
    fn a_touchdown_is_felt_by_the_accelerometer() {
        // Dropped from 0.5 m at a thrust a little under the weight: the accelerometer's
        // vertical, integrated, gives back the whole stop (a real one feels the shock),
        // bounces included.
        let mut p = Plant::new(params(), 0.0);
        p.x[idx::Z] = 0.5;
        p.on_ground = false;
        p.w_cmd_rad_s = [w_hover_rad_s(1.55) * 0.97; 4];
        p.w_rad_s = p.w_cmd_rad_s;
        let mut v_before = 0.0;
        let mut dv_felt = 0.0;
        for _ in 0..5000 {
            let vz = p.velocity_m_s()[2];
            p.step(1000);
            if p.on_ground || dv_felt > 0.0 {
                dv_felt += (p.specific_force_m_s2[2] - GRAVITY_M_S2) * 1e-3;
            } else {
                v_before = vz;
            }
            if dv_felt > 0.0 && p.stop_left_us <= 0 && p.on_ground {
                break;
            }
        }
        assert!(v_before < -0.3, "{v_before}");
        assert!(
            (dv_felt + v_before).abs() < 0.05,
            "felt {dv_felt} m/s of a {v_before} m/s touchdown"
        );
    }

    #[test]
    fn hover_thrust_holds_and_more_climbs() {
        let mut p = Plant::new(params(), 0.0);
        let w = w_hover_rad_s(1.55);
        p.w_cmd_rad_s = [w * 1.05; 4];
        for _ in 0..1000 {
            p.step(1000);
        }
        assert!(!p.on_ground);
        let z1 = p.position_m()[2];
        assert!(z1 > 0.1, "{z1}");
        // Level: no torque with equal motors.
        assert!(p.euler_rad()[0].abs() < 1e-9 && p.euler_rad()[1].abs() < 1e-9);
        // The accelerometer reads the thrust.
        assert!(
            (p.specific_force_m_s2[2] - GRAVITY_M_S2 * 1.1025).abs() < 0.05,
            "{:?}",
            p.specific_force_m_s2
        );
    }

    #[test]
    fn rotation_matches_the_filter_kinematics() {
        let r = rotation(0.1, -0.2, 0.3);
        // Orthonormal.
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        // Gravity in the body frame as the filter's velocity equations have it.
        let g = mul_t(&r, &[0.0, 0.0, -GRAVITY_M_S2]);
        let (psi, phi) = (0.1f64, -0.2f64);
        assert!((g[0] - GRAVITY_M_S2 * phi.sin()).abs() < 1e-12);
        assert!((g[1] + GRAVITY_M_S2 * phi.cos() * psi.sin()).abs() < 1e-12);
        assert!((g[2] + GRAVITY_M_S2 * phi.cos() * psi.cos()).abs() < 1e-12);
    }
}
