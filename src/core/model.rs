//! Physical model of the uQuad: constants, thrust and drag-torque polynomials, hover speed.
//!
//! Spec sections 3.2 and 4.1 (parameters) and 4.2 (w_hover, w_min). Units: kg, m, s, N,
//! N·m, rad/s.

/// Gravity, m/s².
pub const GRAVITY_M_S2: f64 = 9.81;
/// Body inertia about x and y, kg·m².
pub const IXX_KG_M2: f64 = 0.0232;
pub const IYY_KG_M2: f64 = 0.0232;
/// Body inertia about z, kg·m².
pub const IZZ_KG_M2: f64 = 0.0437;
/// Rotor inertia, kg·m².
pub const IZZM_KG_M2: f64 = 1.54e-5;
/// Arm length (centre to motor), m.
pub const ARM_LENGTH_M: f64 = 0.29;
/// Distance from the geometric centre to the centre of mass, m (linearisation only).
pub const D_CENTER_MASS_M: f64 = 0.07;
/// Thrust T(w) = F_B1·w² + F_B2·w, N with w in rad/s.
pub const F_B1: f64 = 4.60160135072435e-05;
pub const F_B2: f64 = -0.00103822726273726;
/// Drag torque Q(w) = M_D1·w² + M_D2·w, N·m.
pub const M_D1: f64 = 3.4734e-6;
pub const M_D2: f64 = -1.3205e-4;
/// Highest motor speed of the 2012 flights, rad/s (`MOT_W_MAX`).
pub const W_MAX_2012_RAD_S: f64 = 368.0;

/// Thrust of one motor, N.
pub fn thrust_n(w_rad_s: f64) -> f64 {
    F_B1 * w_rad_s * w_rad_s + F_B2 * w_rad_s
}

/// Drag torque of one motor, N·m.
pub fn drag_nm(w_rad_s: f64) -> f64 {
    M_D1 * w_rad_s * w_rad_s + M_D2 * w_rad_s
}

/// Motor speed at which four motors hold `mass_kg` (positive root of F_B1·w² + F_B2·w = g·m/4).
pub fn w_hover_rad_s(mass_kg: f64) -> f64 {
    let c = GRAVITY_M_S2 * mass_kg / 4.0;
    (-F_B2 + (F_B2 * F_B2 + 4.0 * F_B1 * c).sqrt()) / (2.0 * F_B1)
}

/// The mass four motors hold at `w_rad_s`, kg: the inverse of `w_hover_rad_s`.
pub fn mass_hovering_at_kg(w_rad_s: f64) -> f64 {
    4.0 * thrust_n(w_rad_s) / GRAVITY_M_S2
}

/// The mass at which `MotorLimits::new(mass, w_max_rad_s)` has the minimum `w_min_rad_s`, kg:
/// hover midway between the two (for w_min ≤ w_max). Lighter, w_min is lower.
pub fn mass_for_w_min_kg(w_min_rad_s: f64, w_max_rad_s: f64) -> f64 {
    mass_hovering_at_kg(0.5 * (w_min_rad_s + w_max_rad_s))
}

/// Motor speed limits around hover: w_hover clamped to w_max, and the symmetric minimum
/// `w_min = w_hover − (w_max − w_hover)` (spec 4.2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorLimits {
    pub w_hover_rad_s: f64,
    pub w_min_rad_s: f64,
    pub w_max_rad_s: f64,
}

impl MotorLimits {
    pub fn new(mass_kg: f64, w_max_rad_s: f64) -> Self {
        let w_hover = w_hover_rad_s(mass_kg).min(w_max_rad_s);
        MotorLimits {
            w_hover_rad_s: w_hover,
            w_min_rad_s: w_hover - (w_max_rad_s - w_hover),
            w_max_rad_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_speeds_match_the_spec() {
        for (m, w) in [(1.55, 298.9217), (1.70, 312.4980), (0.70, 204.7622)] {
            assert!(
                (w_hover_rad_s(m) - w).abs() < 1e-4,
                "{m}: {}",
                w_hover_rad_s(m)
            );
            assert!((4.0 * thrust_n(w_hover_rad_s(m)) - GRAVITY_M_S2 * m).abs() < 1e-12);
        }
        for m in [0.5, 1.0, 1.55, 2.2] {
            assert!((mass_hovering_at_kg(w_hover_rad_s(m)) - m).abs() < 1e-12);
            let l = MotorLimits::new(m, W_MAX_2012_RAD_S);
            let back = mass_for_w_min_kg(l.w_min_rad_s, W_MAX_2012_RAD_S);
            assert!((back - m).abs() < 1e-12, "{m}: {back}");
        }
        let l = MotorLimits::new(1.55, W_MAX_2012_RAD_S);
        // The floor w.log shows for the 2012-05-25 flight.
        assert!(
            (l.w_min_rad_s - 229.843_428_625_595_3).abs() < 1e-9,
            "{}",
            l.w_min_rad_s
        );
    }
}
