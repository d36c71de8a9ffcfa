//! Elementary functions from a portable implementation (the `libm` crate, a port of musl's),
//! so the estimator gives the same bits on the BeagleBoard's ARM as on x86: platform C
//! libraries differ in the last bit of sin, cos, tan, atan2, asin and pow, and the logs print
//! up to 15 decimals. (The spec's formulas of sections 2 and 3 use these.)

pub fn sin(x: f64) -> f64 {
    libm::sin(x)
}

pub fn cos(x: f64) -> f64 {
    libm::cos(x)
}

pub fn sin_cos(x: f64) -> (f64, f64) {
    libm::sincos(x)
}

pub fn tan(x: f64) -> f64 {
    libm::tan(x)
}

pub fn atan2(y: f64, x: f64) -> f64 {
    libm::atan2(y, x)
}

pub fn asin(x: f64) -> f64 {
    libm::asin(x)
}

pub fn pow(x: f64, y: f64) -> f64 {
    libm::pow(x, y)
}

/// Body-to-inertial rotation (ZYX: yaw θ, pitch φ, roll ψ), as the filter's kinematics use.
/// With std's sin and cos: for the simulator's physics and the ground station's telemetry,
/// never for a logged estimate.
pub fn rotation(psi: f64, phi: f64, theta: f64) -> [[f64; 3]; 3] {
    rotation_of(psi.sin_cos(), phi.sin_cos(), theta.sin_cos())
}

/// [`rotation`] from this module's portable sine and cosine: for what a replay must give again
/// on any platform (the controller's set point along a path, the filter's GPS velocity rows).
pub fn rotation_portable(psi: f64, phi: f64, theta: f64) -> [[f64; 3]; 3] {
    let sc = |a: f64| (sin(a), cos(a));
    rotation_of(sc(psi), sc(phi), sc(theta))
}

/// The ZYX rotation from the sines and cosines of roll, pitch and yaw.
fn rotation_of(
    (sps, cps): (f64, f64),
    (sph, cph): (f64, f64),
    (sth, cth): (f64, f64),
) -> [[f64; 3]; 3] {
    [
        [
            cph * cth,
            cth * sph * sps - cps * sth,
            sps * sth + cps * cth * sph,
        ],
        [
            cph * sth,
            sth * sph * sps + cps * cth,
            cps * sth * sph - cth * sps,
        ],
        [-sph, cph * sps, cph * cps],
    ]
}

/// `a` wrapped into [-π, π).
pub fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    a - two_pi * ((a + std::f64::consts::PI) / two_pi).floor()
}
