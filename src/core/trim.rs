//! The vehicle's steady state along a path (its trim): attitude, body velocity and rates, and
//! the four motor speeds that hold it, from the spec 3.3 model without its slips (the true
//! rotation in the vertical row) and without the pendulum term (a coordinated turn feels its
//! apparent gravity along the body's z axis, so the offset centre of mass adds no torque).
//!
//! Frames: the heading frame is the inertial frame turned by the vehicle's yaw (x forward,
//! y left, z up). A path is described in it: the direction of travel relative to the nose
//! (`course_rad`), the speed, and for a circle the turn rate (positive: counter-clockwise seen
//! from above, a left turn). Units: m, m/s, rad, rad/s; motor speeds rad/s.

use crate::core::math::{asin, atan2, cos, sin};
use crate::core::model::{
    ARM_LENGTH_M, F_B1, F_B2, GRAVITY_M_S2, IXX_KG_M2, IYY_KG_M2, IZZ_KG_M2, IZZM_KG_M2, M_D1,
    M_D2, drag_nm, thrust_n, w_hover_rad_s,
};

/// A path's kind, as the gains are designed for it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PathShape {
    /// At rest in the air.
    Hover,
    /// A straight line at `speed_m_s`, `course_rad` from the nose (0: nose first).
    Straight { speed_m_s: f64, course_rad: f64 },
    /// A circle of `radius_m` at `speed_m_s`, `course_rad` from the nose; `left` turns
    /// counter-clockwise seen from above. The heading turns with the path, so the trim is
    /// steady in the frame that turns with it.
    Circle {
        radius_m: f64,
        speed_m_s: f64,
        course_rad: f64,
        left: bool,
    },
}

impl PathShape {
    /// Velocity in the heading frame, m/s, and the heading's turn rate, rad/s.
    pub fn motion(self) -> ([f64; 3], f64) {
        let (v, course, rate) = match self {
            PathShape::Hover => (0.0, 0.0, 0.0),
            PathShape::Straight {
                speed_m_s,
                course_rad,
            } => (speed_m_s, course_rad, 0.0),
            PathShape::Circle {
                radius_m,
                speed_m_s,
                course_rad,
                left,
            } => {
                let rate = speed_m_s / radius_m;
                (speed_m_s, course_rad, if left { rate } else { -rate })
            }
        };
        ([v * cos(course), v * sin(course), 0.0], rate)
    }
}

/// The steady state along a path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trim {
    /// Roll ψ and pitch φ, rad (yaw is the heading frame's: 0).
    pub psi_rad: f64,
    pub phi_rad: f64,
    /// The heading's turn rate, rad/s.
    pub yaw_rate_rad_s: f64,
    /// Body-frame velocity vqx, vqy, vqz, m/s.
    pub v_body_m_s: [f64; 3],
    /// Body-frame rates wqx, wqy, wqz, rad/s.
    pub w_body_rad_s: [f64; 3],
    /// Motor speeds, rad/s, motor order 0..3.
    pub w_motor_rad_s: [f64; 4],
}

/// Why no trim exists.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrimError {
    #[error("the path needs {tilt_deg:.0}° of tilt; at most 60° is flown")]
    TooSteep { tilt_deg: f64 },
    #[error("no motor speeds give the path's thrust and torques (Newton did not converge)")]
    NoMotorSpeeds,
}

/// The attitude whose thrust axis gives the specific force `f` (heading frame): the body's z
/// axis there is (cψ·sφ, −sψ, cψ·cφ) (ZYX angles).
pub fn attitude_for_force(f: [f64; 3]) -> (f64, f64) {
    let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    (asin(-f[1] / norm), atan2(f[0], f[2]))
}

/// The trim of `shape` for a vehicle of `mass_kg`.
pub fn trim(shape: PathShape, mass_kg: f64) -> Result<Trim, TrimError> {
    let (v_h, rate) = shape.motion();
    // Turning at `rate` with velocity v: the acceleration ẑ·rate × v, toward the centre.
    let acc = [-rate * v_h[1], rate * v_h[0], 0.0];
    let f = [acc[0], acc[1], acc[2] + GRAVITY_M_S2];
    let (psi, phi) = attitude_for_force(f);
    let tilt = (cos(psi) * cos(phi)).acos();
    if tilt > 60f64.to_radians() {
        return Err(TrimError::TooSteep {
            tilt_deg: tilt.to_degrees(),
        });
    }
    let (sps, cps) = (sin(psi), cos(psi));
    let (sph, cph) = (sin(phi), cos(phi));
    // Body velocity = (Ry(φ)·Rx(ψ))ᵀ · v_h.
    let v = [
        cph * v_h[0] - sph * v_h[2],
        sph * sps * v_h[0] + cps * v_h[1] + cph * sps * v_h[2],
        sph * cps * v_h[0] - sps * v_h[1] + cph * cps * v_h[2],
    ];
    // Euler rates (0, 0, rate) in body rates (spec 3.3 rows 3–5 inverted).
    let w = [-rate * sph, rate * cph * sps, rate * cph * cps];
    // Row 8 at rest: the thrust that holds the body's vertical velocity.
    let thrust_total = mass_kg * (GRAVITY_M_S2 * cph * cps - (v[0] * w[1] - v[1] * w[0]));
    let w_motor = motor_speeds(thrust_total, w).ok_or(TrimError::NoMotorSpeeds)?;
    Ok(Trim {
        psi_rad: psi,
        phi_rad: phi,
        yaw_rate_rad_s: rate,
        v_body_m_s: v,
        w_body_rad_s: w,
        w_motor_rad_s: w_motor,
    })
}

/// The torque balance at rates `w` (spec 3.3 rows 9–11 at rest) and the total thrust.
fn residual(m: &[f64; 4], thrust_total: f64, w: [f64; 3]) -> [f64; 4] {
    let t = m.map(thrust_n);
    let big_w = m[0] - m[1] + m[2] - m[3];
    [
        t.iter().sum::<f64>() - thrust_total,
        w[1] * w[2] * (IYY_KG_M2 - IZZ_KG_M2)
            + w[1] * IZZM_KG_M2 * big_w
            + ARM_LENGTH_M * (t[1] - t[3]),
        w[0] * w[2] * (IZZ_KG_M2 - IXX_KG_M2)
            + w[0] * IZZM_KG_M2 * big_w
            + ARM_LENGTH_M * (t[2] - t[0]),
        drag_nm(m[0]) - drag_nm(m[1]) + drag_nm(m[2]) - drag_nm(m[3]),
    ]
}

/// Newton's method on the four motor speeds, from the hover speed of the same thrust.
fn motor_speeds(thrust_total: f64, w: [f64; 3]) -> Option<[f64; 4]> {
    let start = w_hover_rad_s(thrust_total / GRAVITY_M_S2);
    let mut m = [start; 4];
    for _ in 0..20 {
        let r = residual(&m, thrust_total, w);
        if r.iter().all(|v| v.abs() < 1e-13) {
            return Some(m);
        }
        let dt = m.map(|x| 2.0 * F_B1 * x + F_B2);
        let dd = m.map(|x| 2.0 * M_D1 * x + M_D2);
        let (gy, gx) = (w[1] * IZZM_KG_M2, w[0] * IZZM_KG_M2);
        let jac = nalgebra::Matrix4::new(
            dt[0],
            dt[1],
            dt[2],
            dt[3],
            gy,
            -gy + ARM_LENGTH_M * dt[1],
            gy,
            -gy - ARM_LENGTH_M * dt[3],
            gx - ARM_LENGTH_M * dt[0],
            -gx,
            gx + ARM_LENGTH_M * dt[2],
            -gx,
            dd[0],
            -dd[1],
            dd[2],
            -dd[3],
        );
        let step = jac.lu().solve(&nalgebra::Vector4::from(r))?;
        for (x, s) in m.iter_mut().zip(step.iter()) {
            *x -= s;
        }
    }
    let r = residual(&m, thrust_total, w);
    r.iter().all(|v| v.abs() < 1e-9).then_some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The spec 3.3 derivatives of the velocity and rate rows (true vertical row, no bias).
    fn body_derivatives(t: &Trim, mass_kg: f64) -> [f64; 6] {
        let (v, w, m) = (t.v_body_m_s, t.w_body_rad_s, t.w_motor_rad_s);
        let g = GRAVITY_M_S2;
        let (sps, cps, sph, cph) = (
            sin(t.psi_rad),
            cos(t.psi_rad),
            sin(t.phi_rad),
            cos(t.phi_rad),
        );
        let thrust: f64 = m.iter().map(|&x| thrust_n(x)).sum();
        let r = residual(&m, thrust, w);
        [
            v[1] * w[2] - v[2] * w[1] + g * sph,
            v[2] * w[0] - v[0] * w[2] - g * cph * sps,
            v[0] * w[1] - v[1] * w[0] - g * cph * cps + thrust / mass_kg,
            r[1] / IXX_KG_M2,
            r[2] / IYY_KG_M2,
            r[3] / IZZ_KG_M2,
        ]
    }

    #[test]
    fn hover_trim_is_level_at_the_hover_speed() {
        let t = trim(PathShape::Hover, 1.55).unwrap();
        assert_eq!((t.psi_rad, t.phi_rad), (0.0, 0.0));
        for w in t.w_motor_rad_s {
            assert!((w - w_hover_rad_s(1.55)).abs() < 1e-9, "{w}");
        }
    }

    #[test]
    fn straight_flight_is_level_with_the_speed_in_the_body_frame() {
        let t = trim(
            PathShape::Straight {
                speed_m_s: 2.0,
                course_rad: std::f64::consts::FRAC_PI_2,
            },
            1.55,
        )
        .unwrap();
        assert!(t.psi_rad.abs() < 1e-15 && t.phi_rad.abs() < 1e-15);
        assert!(t.v_body_m_s[0].abs() < 1e-12 && (t.v_body_m_s[1] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn a_left_turn_banks_left_and_is_steady() {
        for (left, course) in [(true, 0.0), (false, 0.0), (true, 1.0), (false, -2.5)] {
            let shape = PathShape::Circle {
                radius_m: 5.0,
                speed_m_s: 3.0,
                course_rad: course,
                left,
            };
            let t = trim(shape, 1.55).unwrap();
            for d in body_derivatives(&t, 1.55) {
                assert!(d.abs() < 1e-9, "{shape:?}: {d}");
            }
            // tan(bank) = v²/(r·g); the thrust axis leans toward the centre.
            let bank = (cos(t.psi_rad) * cos(t.phi_rad)).acos();
            assert!((bank.tan() - 9.0 / (5.0 * GRAVITY_M_S2)).abs() < 1e-12);
            if course == 0.0 {
                assert_eq!(t.psi_rad < 0.0, left, "{t:?}");
            }
        }
    }

    #[test]
    fn a_path_too_tight_is_refused() {
        let shape = PathShape::Circle {
            radius_m: 1.0,
            speed_m_s: 10.0,
            course_rad: 0.0,
            left: true,
        };
        assert!(matches!(trim(shape, 1.55), Err(TrimError::TooSteep { .. })));
    }
}
