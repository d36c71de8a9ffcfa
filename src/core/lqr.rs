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
use crate::core::model::{
    ARM_LENGTH_M, D_CENTER_MASS_M, F_B1, F_B2, GRAVITY_M_S2, IXX_KG_M2, IYY_KG_M2, IZZ_KG_M2, M_D1,
    M_D2, w_hover_rad_s,
};
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
    let mut ae = Mat16::zeros();
    let mut be = Mat16x4::zeros();
    ae.fixed_view_mut::<12, 12>(0, 0).copy_from(&a);
    be.fixed_view_mut::<12, 4>(0, 0).copy_from(&b);
    for (k, &state) in integrators.states().iter().enumerate() {
        ae[(12 + k, state)] = 1.0;
    }
    (ae, be)
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
        "the hover model with integrators on {integrators} is not stabilisable: closed-loop \
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
    let (phi, gamma) = discretise(&a, &b, TS_S);
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
