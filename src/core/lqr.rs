//! LQR gain design at hover: linearisation, integrator extension, discretisation, discrete
//! algebraic Riccati equation, gain split.
//!
//! Spec section 4.5. The model is linearised at ψ = φ = θ = 0, zero velocities and rates and
//! w = w_hover(m) on all four motors, extended with four integrators, discretised with the
//! matrix exponential at Ts = 0.01 s, and the DARE is solved by the structured doubling
//! algorithm (quadratic convergence) to a relative residual below 1e-9 — not the original's
//! ‖ΔK‖ < 1e-5 stopping rule. Gains follow the gain files' convention
//! w = w_hover + K·e + K_int·x_int with e = set point − state and x_int = ∫e.

use crate::core::control::Integrators;
use crate::core::math::{cos, sin};
use crate::core::model::{
    ARM_LENGTH_M, D_CENTER_MASS_M, F_B1, F_B2, GRAVITY_M_S2, IXX_KG_M2, IYY_KG_M2, IZZ_KG_M2,
    IZZM_KG_M2, M_D1, M_D2, w_hover_rad_s,
};
use crate::core::trim::Trim;
use nalgebra::{Complex, SMatrix, SVector};

/// States of the extended model: 12 + 4 integrators.
pub const N_EXT: usize = 16;
/// Discretisation period, s.
pub const TS_S: f64 = 0.01;
/// Residual the solution must reach, relative to ‖P‖.
pub const RESIDUAL_GOAL: f64 = 1e-9;
/// Closed-loop eigenvalues with modulus above this are treated as on the unit circle.
pub const UNIT_CIRCLE_TOL: f64 = 1e-7;

pub type Mat16 = SMatrix<f64, N_EXT, N_EXT>;
pub type Mat16x4 = SMatrix<f64, N_EXT, 4>;
pub type Mat4 = SMatrix<f64, 4, 4>;
pub type Gain = SMatrix<f64, 4, N_EXT>;

/// The continuous linear model at hover (spec 4.5), 12 states, 4 inputs.
pub fn hover_model(mass_kg: f64) -> (SMatrix<f64, 12, 12>, SMatrix<f64, 12, 4>) {
    let g = GRAVITY_M_S2;
    let w = w_hover_rad_s(mass_kg);
    let mut a = SMatrix::<f64, 12, 12>::zeros();
    // Position kinematics at zero attitude: body velocity = inertial velocity.
    a[(0, 6)] = 1.0;
    a[(1, 7)] = 1.0;
    a[(2, 8)] = 1.0;
    // Attitude kinematics.
    a[(3, 9)] = 1.0;
    a[(4, 10)] = 1.0;
    a[(5, 11)] = 1.0;
    // Gravity in the body frame.
    a[(6, 4)] = g;
    a[(7, 3)] = -g;
    // The centre of mass below the rotor plane: a pendulum term (D_CENTER_MASS_M).
    a[(9, 3)] = -D_CENTER_MASS_M * mass_kg * g / IXX_KG_M2;
    a[(10, 4)] = -D_CENTER_MASS_M * mass_kg * g / IYY_KG_M2;
    let mut b = SMatrix::<f64, 12, 4>::zeros();
    let dthrust = 2.0 * F_B1 * w + F_B2;
    let ddrag = 2.0 * M_D1 * w + M_D2;
    for j in 0..4 {
        b[(8, j)] = dthrust / mass_kg;
        // Motors 0 and 2 spin one way, 1 and 3 the other.
        b[(11, j)] = if j % 2 == 0 { -ddrag } else { ddrag } / IZZ_KG_M2;
    }
    b[(9, 1)] = ARM_LENGTH_M * dthrust / IXX_KG_M2;
    b[(9, 3)] = -ARM_LENGTH_M * dthrust / IXX_KG_M2;
    b[(10, 0)] = -ARM_LENGTH_M * dthrust / IYY_KG_M2;
    b[(10, 2)] = ARM_LENGTH_M * dthrust / IYY_KG_M2;
    (a, b)
}

/// The model extended with integrators of the listed states (ẋ_int,k = x_state(k)).
pub fn extended_model(mass_kg: f64, integrators: Integrators) -> (Mat16, Mat16x4) {
    let (a, b) = hover_model(mass_kg);
    extend(&a, &b, integrators)
}

/// `a`, `b` extended with integrators of the listed states.
pub fn extend(
    a: &SMatrix<f64, 12, 12>,
    b: &SMatrix<f64, 12, 4>,
    integrators: Integrators,
) -> (Mat16, Mat16x4) {
    let mut ae = Mat16::zeros();
    let mut be = Mat16x4::zeros();
    ae.fixed_view_mut::<12, 12>(0, 0).copy_from(a);
    be.fixed_view_mut::<12, 4>(0, 0).copy_from(b);
    for (k, &state) in integrators.states().iter().enumerate() {
        ae[(12 + k, state)] = 1.0;
    }
    (ae, be)
}

/// The continuous linear model about a path's trim (spec 4.5 for hover and straight flight;
/// a circle in the frame that turns with the heading, which adds the −Ω × p terms to rows 0
/// and 1). Position rows use the true rotation (the original's kinematics carry slips in rows
/// 0 and 2); the yaw is the heading frame's (0); the other rows are spec 4.5's, with the
/// correct partials where the original's code had ωz for ωx (row 10).
pub fn path_model(mass_kg: f64, t: &Trim) -> (SMatrix<f64, 12, 12>, SMatrix<f64, 12, 4>) {
    let mut a = SMatrix::<f64, 12, 12>::zeros();
    position_rows(&mut a, t);
    rate_rows(&mut a, mass_kg, t);
    (a, path_inputs(mass_kg, t))
}

/// Rows 0–2: ∂(R(ψ, φ, θ)·v)/∂(ψ, φ, θ, v) at θ = 0, and the turning frame's −Ω × p.
fn position_rows(a: &mut SMatrix<f64, 12, 12>, t: &Trim) {
    let (sps, cps) = (sin(t.psi_rad), cos(t.psi_rad));
    let (sph, cph) = (sin(t.phi_rad), cos(t.phi_rad));
    let [vx, vy, vz] = t.v_body_m_s;
    let r = [
        [cph, sph * sps, cps * sph],
        [0.0, cps, -sps],
        [-sph, cph * sps, cph * cps],
    ];
    for (i, row) in r.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            a[(i, 6 + j)] = *v;
        }
    }
    a[(0, 3)] = vy * sph * cps - vz * sps * sph;
    a[(1, 3)] = -vy * sps - vz * cps;
    a[(2, 3)] = vy * cph * cps - vz * cph * sps;
    a[(0, 4)] = -vx * sph + vy * cph * sps + vz * cps * cph;
    a[(2, 4)] = -vx * cph - vy * sph * sps - vz * sph * cps;
    a[(0, 5)] = -(cps * vy - sps * vz);
    a[(1, 5)] = cph * vx + sph * sps * vy + cps * sph * vz;
    a[(0, 1)] = t.yaw_rate_rad_s;
    a[(1, 0)] = -t.yaw_rate_rad_s;
}

/// Rows 3–10: attitude kinematics, body-frame velocity and rate dynamics (spec 4.5).
fn rate_rows(a: &mut SMatrix<f64, 12, 12>, mass_kg: f64, t: &Trim) {
    let g = GRAVITY_M_S2;
    let (sps, cps) = (sin(t.psi_rad), cos(t.psi_rad));
    let (sph, cph) = (sin(t.phi_rad), cos(t.phi_rad));
    let tph = sph / cph;
    let [vx, vy, vz] = t.v_body_m_s;
    let [wx, wy, wz] = t.w_body_rad_s;
    let m = t.w_motor_rad_s;
    let big_w = m[0] - m[1] + m[2] - m[3];
    a[(3, 3)] = wy * cps * tph - wz * sps * tph;
    a[(3, 4)] = (wz * cps + wy * sps) * (tph * tph + 1.0);
    a[(3, 9)] = 1.0;
    a[(3, 10)] = sps * tph;
    a[(3, 11)] = cps * tph;
    a[(4, 3)] = -wy * sps - wz * cps;
    a[(4, 10)] = cps;
    a[(4, 11)] = -sps;
    a[(5, 3)] = (wy * cps - wz * sps) / cph;
    a[(5, 4)] = (wy * sps * sph + wz * cps * sph) / (cph * cph);
    a[(5, 10)] = sps / cph;
    a[(5, 11)] = cps / cph;
    a[(6, 4)] = g * cph;
    a[(6, 7)] = wz;
    a[(6, 8)] = -wy;
    a[(6, 10)] = -vz;
    a[(6, 11)] = vy;
    a[(7, 3)] = -g * cps * cph;
    a[(7, 4)] = g * sps * sph;
    a[(7, 6)] = -wz;
    a[(7, 8)] = wx;
    a[(7, 9)] = vz;
    a[(7, 11)] = -vx;
    a[(8, 3)] = g * sps * cph;
    a[(8, 4)] = g * cps * sph;
    a[(8, 6)] = wy;
    a[(8, 7)] = -wx;
    a[(8, 9)] = -vy;
    a[(8, 10)] = vx;
    a[(9, 3)] = -D_CENTER_MASS_M * mass_kg * g * cph * cps / IXX_KG_M2;
    a[(9, 4)] = D_CENTER_MASS_M * mass_kg * g * sph * sps / IXX_KG_M2;
    a[(9, 10)] = (IZZM_KG_M2 * big_w + (IYY_KG_M2 - IZZ_KG_M2) * wz) / IXX_KG_M2;
    a[(9, 11)] = (IYY_KG_M2 - IZZ_KG_M2) * wy / IXX_KG_M2;
    a[(10, 4)] = -D_CENTER_MASS_M * mass_kg * g * cph / IYY_KG_M2;
    a[(10, 9)] = (IZZM_KG_M2 * big_w + (IZZ_KG_M2 - IXX_KG_M2) * wz) / IYY_KG_M2;
    a[(10, 11)] = (IZZ_KG_M2 - IXX_KG_M2) * wx / IYY_KG_M2;
}

/// B about the trim: thrust and drag slopes at each motor's speed, and the rotors'
/// gyroscopic coupling with the body's rates.
fn path_inputs(mass_kg: f64, t: &Trim) -> SMatrix<f64, 12, 4> {
    let m = t.w_motor_rad_s;
    let dt = m.map(|w| 2.0 * F_B1 * w + F_B2);
    let dd = m.map(|w| 2.0 * M_D1 * w + M_D2);
    let [wx, wy, _] = t.w_body_rad_s;
    let (gy, gx) = (wy * IZZM_KG_M2, wx * IZZM_KG_M2);
    let l = ARM_LENGTH_M;
    let mut b = SMatrix::<f64, 12, 4>::zeros();
    for j in 0..4 {
        b[(8, j)] = dt[j] / mass_kg;
        b[(11, j)] = if j % 2 == 0 { -dd[j] } else { dd[j] } / IZZ_KG_M2;
    }
    let roll = [gy, -gy + l * dt[1], gy, -gy - l * dt[3]];
    let pitch = [gx - l * dt[0], -gx, gx + l * dt[2], -gx];
    for j in 0..4 {
        b[(9, j)] = roll[j] / IXX_KG_M2;
        b[(10, j)] = pitch[j] / IYY_KG_M2;
    }
    b
}

/// Zero-order-hold discretisation: expm([[A, B], [0, 0]]·Ts) = [[Φ, Γ], [0, I]].
pub fn discretise(a: &Mat16, b: &Mat16x4, ts_s: f64) -> (Mat16, Mat16x4) {
    let mut m = SMatrix::<f64, 20, 20>::zeros();
    m.fixed_view_mut::<16, 16>(0, 0).copy_from(&(a * ts_s));
    m.fixed_view_mut::<16, 4>(0, 16).copy_from(&(b * ts_s));
    let e = m.exp();
    (
        e.fixed_view::<16, 16>(0, 0).into_owned(),
        e.fixed_view::<16, 4>(0, 16).into_owned(),
    )
}

/// Why a design failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LqrError {
    #[error(
        "the linear model with integrators on {integrators} is not stabilisable: closed-loop \
         eigenvalues stay on the unit circle ({eigenvalues}). {why}"
    )]
    NotStabilisable {
        integrators: &'static str,
        eigenvalues: String,
        why: &'static str,
    },
    #[error("the Riccati solution did not converge (relative residual {residual:e})")]
    NoConvergence { residual: f64 },
    #[error("R is not positive definite")]
    RNotPositiveDefinite,
}

/// A solved design.
#[derive(Debug, Clone)]
pub struct Design {
    /// Riccati solution.
    pub p: Mat16,
    /// Full gain with the u = −K_lqr·[δx; z] convention (z = ∫δx).
    pub k_lqr: Gain,
    /// ‖residual‖_F / ‖P‖_F.
    pub residual_rel: f64,
    /// Largest closed-loop eigenvalue modulus of Φ − Γ·K_lqr.
    pub spectral_radius: f64,
    pub discrete: (Mat16, Mat16x4),
}

impl Design {
    /// Proportional gains (4 × 12) in the gain-file convention: w − w_hover = K·e.
    pub fn k_prop(&self) -> SMatrix<f64, 4, 12> {
        // e = −δx, so K_lqr acting on δx with a minus sign is K acting on e.
        self.k_lqr.fixed_view::<4, 12>(0, 0).into_owned()
    }

    /// Integral gains (4 × 4): the controller's x_int = ∫e = −z, so −K_lqr·z = K_int·x_int.
    pub fn k_int(&self) -> Mat4 {
        self.k_lqr.fixed_view::<4, 4>(0, 12).into_owned()
    }
}

/// The DARE residual Φᵀ P Φ − P − ΦᵀPΓ (R + ΓᵀPΓ)⁻¹ ΓᵀPΦ + Q, relative to ‖P‖_F.
pub fn dare_residual(phi: &Mat16, gamma: &Mat16x4, q: &Mat16, r: &Mat4, p: &Mat16) -> f64 {
    let gpg = r + gamma.transpose() * p * gamma;
    let gpf = gamma.transpose() * p * phi;
    let Some(inv) = gpg.try_inverse() else {
        return f64::INFINITY;
    };
    let res = phi.transpose() * p * phi - p - gpf.transpose() * inv * gpf + q;
    res.norm() / p.norm()
}

/// The gain for a Riccati solution: K = (R + ΓᵀPΓ)⁻¹ ΓᵀPΦ.
pub fn gain(phi: &Mat16, gamma: &Mat16x4, r: &Mat4, p: &Mat16) -> Option<Gain> {
    let gpg = r + gamma.transpose() * p * gamma;
    let chol = gpg.cholesky()?;
    Some(chol.solve(&(gamma.transpose() * p * phi)))
}

/// Solves the DARE by the structured doubling algorithm: A₀ = Φ, G₀ = Γ R⁻¹ Γᵀ, H₀ = Q;
/// W = I + G H; A ← A W⁻¹ A; G ← G + A W⁻¹ G Aᵀ; H ← H + Aᵀ H W⁻¹ A. H converges to the
/// stabilising solution when one exists.
pub fn solve_dare(phi: &Mat16, gamma: &Mat16x4, q: &Mat16, r: &Mat4) -> Result<Mat16, LqrError> {
    let r_inv = r
        .cholesky()
        .map(|c| c.inverse())
        .ok_or(LqrError::RNotPositiveDefinite)?;
    let mut a = *phi;
    let mut g = gamma * r_inv * gamma.transpose();
    let mut h = *q;
    for _ in 0..100 {
        let w = Mat16::identity() + g * h;
        let Some(w_inv) = w.try_inverse() else {
            break;
        };
        let a_next = a * w_inv * a;
        let g_next = g + a * w_inv * g * a.transpose();
        let h_next = h + a.transpose() * h * w_inv * a;
        if !h_next.iter().all(|v| v.is_finite()) {
            break;
        }
        let change = (h_next - h).norm() / h_next.norm();
        a = a_next;
        // Symmetrise: G and H are symmetric in exact arithmetic.
        g = (g_next + g_next.transpose()) * 0.5;
        h = (h_next + h_next.transpose()) * 0.5;
        if change < 1e-15 {
            break;
        }
    }
    Ok(h)
}

fn closed_loop_eigenvalues(phi: &Mat16, gamma: &Mat16x4, k: &Gain) -> SVector<Complex<f64>, 16> {
    (phi - gamma * k).complex_eigenvalues()
}

/// Designs the hover gains for `mass_kg` with the given integrators and weights.
pub fn design(
    mass_kg: f64,
    integrators: Integrators,
    q: &Mat16,
    r: &Mat4,
) -> Result<Design, LqrError> {
    let (a, b) = extended_model(mass_kg, integrators);
    design_extended(&a, &b, integrators, q, r)
}

/// Designs the gains about a path's trim (`uquad lqr --path`, the mission's segments).
pub fn design_path(
    mass_kg: f64,
    trim: &Trim,
    integrators: Integrators,
    q: &Mat16,
    r: &Mat4,
) -> Result<Design, LqrError> {
    let (a, b) = path_model(mass_kg, trim);
    let (a, b) = extend(&a, &b, integrators);
    design_extended(&a, &b, integrators, q, r)
}

/// Discretises the extended model and solves its Riccati equation.
fn design_extended(
    a: &Mat16,
    b: &Mat16x4,
    integrators: Integrators,
    q: &Mat16,
    r: &Mat4,
) -> Result<Design, LqrError> {
    let (phi, gamma) = discretise(a, b, TS_S);
    let p = solve_dare(&phi, &gamma, q, r)?;
    let residual_rel = dare_residual(&phi, &gamma, q, r, &p);
    let k = gain(&phi, &gamma, r, &p);
    let eig = k.as_ref().map(|k| closed_loop_eigenvalues(&phi, &gamma, k));
    let spectral_radius = eig.as_ref().map_or(f64::INFINITY, |e| {
        e.iter().map(|c| c.norm()).fold(0.0, f64::max)
    });
    if spectral_radius >= 1.0 - UNIT_CIRCLE_TOL || !residual_rel.is_finite() {
        // Uncontrollable modes keep their eigenvalues under any feedback: report those of
        // the best gain found, or of the open loop if there is none.
        let ev = match eig {
            Some(e) => e,
            None => phi.complex_eigenvalues(),
        };
        let on_circle: Vec<String> = ev
            .iter()
            .filter(|c| c.norm() >= 1.0 - UNIT_CIRCLE_TOL)
            .map(|c| format!("{:.6}{:+.6}i", c.re, c.im))
            .collect();
        return Err(LqrError::NotStabilisable {
            integrators: integrators.name(),
            eigenvalues: if on_circle.is_empty() {
                "none found; the solver diverged".to_string()
            } else {
                on_circle.join(", ")
            },
            why: match integrators {
                Integrators::PsiPhiZTheta => {
                    "At hover vqx' = g·φ and vqy' = −g·ψ, so vqx − g·∫φ and vqy + g·∫ψ do not \
                     change whatever the motors do; integrate x and y instead \
                     (--integrators x,y,z,theta)."
                }
                _ => "Some mode of the extended model cannot be moved by the motors.",
            },
        });
    }
    if residual_rel >= RESIDUAL_GOAL {
        return Err(LqrError::NoConvergence {
            residual: residual_rel,
        });
    }
    let k_lqr = k.ok_or(LqrError::NoConvergence {
        residual: residual_rel,
    })?;
    Ok(Design {
        p,
        k_lqr,
        residual_rel,
        spectral_radius,
        discrete: (phi, gamma),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weights() -> (Mat16, Mat4) {
        let mut qd = [1.0; 16];
        qd[3] = 1e3;
        qd[4] = 1e3;
        qd[5] = 1e3;
        (
            Mat16::from_diagonal(&SVector::from(qd)),
            Mat4::identity() * 0.1,
        )
    }

    #[test]
    fn model_matches_the_nonlinear_model_at_hover() {
        // Finite differences of the EKF process model (without its bias states) give A and B,
        // apart from the pendulum term the EKF model does not have.
        use crate::core::ekf::{State, process};
        let m = 1.55;
        let w = w_hover_rad_s(m);
        let (a, b) = hover_model(m);
        let t = 1e-3;
        let h = 1e-6;
        for j in 0..12 {
            let mut xp = State::zeros();
            xp[j] = h;
            let mut xm = State::zeros();
            xm[j] = -h;
            // process() returns x + T·f(x): take f.
            let f = |x: &State| (process(x, &[w; 4], t, m, false) - x) / t;
            let d = (f(&xp) - f(&xm)) / (2.0 * h);
            for i in 0..12 {
                let expected = if (i, j) == (9, 3) || (i, j) == (10, 4) {
                    0.0
                } else {
                    a[(i, j)]
                };
                assert!(
                    (d[i] - expected).abs() < 1e-6,
                    "A[{i}][{j}] {} vs {}",
                    a[(i, j)],
                    d[i]
                );
            }
        }
        for j in 0..4 {
            let mut up = [w; 4];
            up[j] += h;
            let mut um = [w; 4];
            um[j] -= h;
            let z = State::zeros();
            let d = (process(&z, &up, t, m, false) - process(&z, &um, t, m, false)) / (2.0 * h * t);
            for i in 0..12 {
                assert!(
                    (d[i] - b[(i, j)]).abs() < 1e-6,
                    "B[{i}][{j}] {} vs {}",
                    b[(i, j)],
                    d[i]
                );
            }
        }
    }

    /// The continuous nonlinear model the path model linearises: spec 3.3 with the true
    /// rotation, the pendulum term, no bias, position in a frame turning at `rate` and yaw
    /// relative to it.
    fn f_turning(x: &[f64; 12], u: &[f64; 4], m: f64, rate: f64) -> [f64; 12] {
        use crate::core::model::{drag_nm, thrust_n};
        let (psi, phi, th) = (x[3], x[4], x[5]);
        let (v, w) = ([x[6], x[7], x[8]], [x[9], x[10], x[11]]);
        let r = crate::core::math::rotation(psi, phi, th);
        let p = |i: usize| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2];
        let (sps, cps, sph, cph) = (psi.sin(), psi.cos(), phi.sin(), phi.cos());
        let t = u.map(thrust_n);
        let big_w = u[0] - u[1] + u[2] - u[3];
        let g = GRAVITY_M_S2;
        let dmg = D_CENTER_MASS_M * m * g;
        [
            p(0) + rate * x[1],
            p(1) - rate * x[0],
            p(2),
            w[0] + w[2] * sph / cph * cps + w[1] * sph / cph * sps,
            w[1] * cps - w[2] * sps,
            (w[2] * cps + w[1] * sps) / cph - rate,
            v[1] * w[2] - v[2] * w[1] + g * sph,
            v[2] * w[0] - v[0] * w[2] - g * cph * sps,
            v[0] * w[1] - v[1] * w[0] - g * cph * cps + t.iter().sum::<f64>() / m,
            (w[1] * w[2] * (IYY_KG_M2 - IZZ_KG_M2)
                + w[1] * IZZM_KG_M2 * big_w
                + ARM_LENGTH_M * (t[1] - t[3])
                - dmg * cph * sps)
                / IXX_KG_M2,
            (w[0] * w[2] * (IZZ_KG_M2 - IXX_KG_M2)
                + w[0] * IZZM_KG_M2 * big_w
                + ARM_LENGTH_M * (t[2] - t[0])
                - dmg * sph)
                / IYY_KG_M2,
            -(drag_nm(u[0]) - drag_nm(u[1]) + drag_nm(u[2]) - drag_nm(u[3])) / IZZ_KG_M2,
        ]
    }

    #[test]
    fn path_model_is_the_jacobian_of_the_turning_model() {
        use crate::core::trim::{PathShape, trim};
        let m = 1.55;
        for shape in [
            PathShape::Hover,
            PathShape::Straight {
                speed_m_s: 1.5,
                course_rad: 0.7,
            },
            PathShape::Circle {
                radius_m: 4.0,
                speed_m_s: 3.0,
                course_rad: -0.4,
                left: false,
            },
        ] {
            let t = trim(shape, m).unwrap();
            let (a, b) = path_model(m, &t);
            let mut x0 = [0.0; 12];
            x0[3] = t.psi_rad;
            x0[4] = t.phi_rad;
            x0[6..9].copy_from_slice(&t.v_body_m_s);
            x0[9..12].copy_from_slice(&t.w_body_rad_s);
            let u0 = t.w_motor_rad_s;
            let rate = t.yaw_rate_rad_s;
            let h = 1e-6;
            for j in 0..16 {
                let (mut xp, mut xm, mut up, mut um) = (x0, x0, u0, u0);
                if j < 12 {
                    xp[j] += h;
                    xm[j] -= h;
                } else {
                    up[j - 12] += h;
                    um[j - 12] -= h;
                }
                let (fp, fm) = (f_turning(&xp, &up, m, rate), f_turning(&xm, &um, m, rate));
                for i in 0..12 {
                    let d = (fp[i] - fm[i]) / (2.0 * h);
                    let ours = if j < 12 { a[(i, j)] } else { b[(i, j - 12)] };
                    assert!(
                        (d - ours).abs() < 1e-6,
                        "{shape:?} [{i}][{j}]: {ours} vs {d}"
                    );
                }
            }
        }
    }

    #[test]
    fn path_model_at_hover_is_the_hover_model() {
        use crate::core::trim::{PathShape, trim};
        let t = trim(PathShape::Hover, 1.55).unwrap();
        let (a, b) = path_model(1.55, &t);
        let (ah, bh) = hover_model(1.55);
        assert!((a - ah).norm() < 1e-12 && (b - bh).norm() < 1e-12);
    }

    #[test]
    fn straight_and_circle_designs_stabilise() {
        use crate::core::trim::{PathShape, trim};
        let (q, r) = weights();
        for shape in [
            PathShape::Straight {
                speed_m_s: 1.0,
                course_rad: 0.0,
            },
            PathShape::Circle {
                radius_m: 5.0,
                speed_m_s: 1.0,
                course_rad: 0.0,
                left: true,
            },
        ] {
            let t = trim(shape, 1.55).unwrap();
            let d = design_path(1.55, &t, Integrators::XYZTheta, &q, &r).unwrap();
            assert!(
                d.residual_rel < RESIDUAL_GOAL && d.spectral_radius < 1.0,
                "{shape:?}"
            );
        }
    }

    #[test]
    fn xyzt_design_converges_and_stabilises() {
        let (q, r) = weights();
        let d = design(1.55, Integrators::XYZTheta, &q, &r).unwrap();
        assert!(d.residual_rel < RESIDUAL_GOAL, "{}", d.residual_rel);
        assert!(d.spectral_radius < 1.0, "{}", d.spectral_radius);
        // Symmetric by construction, positive definite.
        assert!((d.p - d.p.transpose()).norm() < 1e-9 * d.p.norm());
        assert!(d.p.cholesky().is_some());
        // Gains in the gain files' convention: below the set point (e_z > 0) all motors speed up.
        let k = d.k_prop();
        for m in 0..4 {
            assert!(k[(m, 2)] > 0.0 && d.k_int()[(m, 2)] > 0.0, "{k}");
        }
    }

    #[test]
    fn psi_phi_integrators_are_not_stabilisable() {
        let (q, r) = weights();
        let e = design(1.55, Integrators::PsiPhiZTheta, &q, &r).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, LqrError::NotStabilisable { .. }), "{msg}");
        assert!(msg.contains("g·∫φ") && msg.contains("x,y,z,theta"), "{msg}");
        assert!(msg.contains("1.000000"), "{msg}");
    }

    #[test]
    fn discretisation_of_a_double_integrator() {
        // ẍ = u: Φ = [[1, T], [0, 1]], Γ = [T²/2, T].
        let mut a = Mat16::zeros();
        let mut b = Mat16x4::zeros();
        a[(0, 1)] = 1.0;
        b[(1, 0)] = 1.0;
        let (phi, gamma) = discretise(&a, &b, 0.01);
        assert!((phi[(0, 1)] - 0.01).abs() < 1e-15);
        assert!((gamma[(0, 0)] - 0.5e-4).abs() < 1e-15);
        assert!((gamma[(1, 0)] - 0.01).abs() < 1e-15);
    }
}
