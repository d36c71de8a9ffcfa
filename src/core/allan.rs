//! A sensor's noise from a still record: the overlapping Allan deviation and the three terms
//! of IEEE Std 952's model fitted to it. Not in the original's spec (its filter's noise values
//! were found by trial); `uquad noise` prints these figures and the filter noise they imply.
//!
//! The Allan variance of the mean over τ is modelled as N²/τ + (2 ln 2/π)·B² + K²·τ/3:
//! white noise of density N (unit·√s: a single sample of period τ₀ then has the standard
//! deviation N/√τ₀), bias instability B (the flat floor; flicker noise), and a bias random
//! walk of K (unit/√s). The three coefficients are fitted by weighted least squares, each
//! point weighed by its number of independent clusters over its variance squared (the
//! estimate's relative spread), keeping the best fit whose coefficients are all ≥ 0.

/// One point of an Allan deviation curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AllanPoint {
    /// Cluster length, s.
    pub tau_s: f64,
    /// The Allan deviation, the record's unit.
    pub adev: f64,
    /// Independent clusters behind it (samples / cluster length).
    pub clusters: f64,
}

/// The overlapping Allan deviation of `samples` taken every `tau0_s`, at cluster lengths
/// spaced about ten to a decade, up to a ninth of the record (at least 9 clusters).
pub fn allan_deviation(samples: &[f64], tau0_s: f64) -> Vec<AllanPoint> {
    let n = samples.len();
    // θ, the record's integral: θ[k] = τ₀·Σ_{i<k} y_i.
    let mut theta = Vec::with_capacity(n + 1);
    theta.push(0.0);
    let mut acc = 0.0;
    for &y in samples {
        acc += y * tau0_s;
        theta.push(acc);
    }
    let mut out = Vec::new();
    let mut m_f = 1.0f64;
    let mut last_m = 0;
    while (m_f as usize) * 9 <= n {
        let m = m_f as usize;
        m_f *= 10f64.powf(0.1);
        if m == last_m {
            continue;
        }
        last_m = m;
        let tau = m as f64 * tau0_s;
        let terms = n + 1 - 2 * m;
        let sum: f64 = (0..terms)
            .map(|k| {
                let d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
                d * d
            })
            .sum();
        let avar = sum / (2.0 * tau * tau * terms as f64);
        out.push(AllanPoint {
            tau_s: tau,
            adev: avar.sqrt(),
            clusters: n as f64 / m as f64,
        });
    }
    out
}

/// The noise terms of IEEE Std 952's model (see the module's notes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseTerms {
    /// White noise density N, unit·√s (angle random walk for a gyro, velocity random walk for
    /// an accelerometer).
    pub white_density: f64,
    /// One sample's white noise, N/√τ₀, unit.
    pub white_sd: f64,
    /// Bias instability B, unit.
    pub bias_instability: f64,
    /// Bias random walk K, unit/√s.
    pub random_walk: f64,
}

/// (2 ln 2)/π: the Allan variance's floor per B² of flicker noise.
const FLICKER_FLOOR: f64 = 2.0 * std::f64::consts::LN_2 / std::f64::consts::PI;

/// Fits the model to `points` of a record sampled every `tau0_s`; `None` without points.
pub fn fit(points: &[AllanPoint], tau0_s: f64) -> Option<NoiseTerms> {
    let mut best: Option<([f64; 3], f64)> = None;
    // Every non-empty subset of the three terms; a term left out is 0.
    for mask in 1u8..8 {
        let Some(coef) = fit_terms(points, mask) else {
            continue;
        };
        if coef.iter().any(|&c| c < 0.0) {
            continue;
        }
        // Every candidate is scored with the same weights (the points' own variances): each
        // model's own would favour the ones that over-predict.
        let sse = weighted_sse(points, &coef);
        if best.is_none_or(|(_, b)| sse < b) {
            best = Some((coef, sse));
        }
    }
    let ([a, b, c], _) = best?;
    Some(NoiseTerms {
        white_density: a.sqrt(),
        white_sd: (a / tau0_s).sqrt(),
        bias_instability: (b / FLICKER_FLOOR).sqrt(),
        random_walk: (3.0 * c).sqrt(),
    })
}

/// Reweighting rounds: the first weighs each point by its own measured variance, which favours
/// the points that happened to come out low (a fit biased low); the later ones by the fitted
/// model's variance.
const REWEIGHTS: usize = 4;

/// The basis of the model at τ: 1/τ, 1, τ.
fn basis(tau_s: f64) -> [f64; 3] {
    [1.0 / tau_s, 1.0, tau_s]
}

/// The model's variance at τ.
fn model_avar(tau_s: f64, coef: &[f64; 3]) -> f64 {
    basis(tau_s).iter().zip(coef).map(|(b, c)| b * c).sum()
}

/// A point's weight: independent clusters over the variance squared, the variance the
/// model's `by` (the point's own when `None`).
fn weight(p: &AllanPoint, by: Option<&[f64; 3]>) -> f64 {
    let avar = by.map_or(p.adev * p.adev, |c| model_avar(p.tau_s, c));
    if avar > 0.0 {
        p.clusters / (avar * avar)
    } else {
        0.0
    }
}

fn weighted_sse(points: &[AllanPoint], coef: &[f64; 3]) -> f64 {
    points
        .iter()
        .map(|p| {
            let r = p.adev * p.adev - model_avar(p.tau_s, coef);
            weight(p, None) * r * r
        })
        .sum()
}

/// The terms in `mask` (bit i: term i) by iteratively reweighted least squares of the
/// variance.
fn fit_terms(points: &[AllanPoint], mask: u8) -> Option<[f64; 3]> {
    let mut coef = solve_terms(points, mask, None)?;
    for _ in 1..REWEIGHTS {
        if coef.iter().any(|&c| c < 0.0) {
            break;
        }
        coef = solve_terms(points, mask, Some(&coef))?;
    }
    Some(coef)
}

/// One weighted least-squares solve, weights by `by` (see [`weight`]).
fn solve_terms(points: &[AllanPoint], mask: u8, by: Option<&[f64; 3]>) -> Option<[f64; 3]> {
    let used: Vec<usize> = (0..3).filter(|i| mask & (1 << i) != 0).collect();
    let k = used.len();
    let mut ata = nalgebra::DMatrix::<f64>::zeros(k, k);
    let mut atb = nalgebra::DVector::<f64>::zeros(k);
    for p in points {
        let w = weight(p, by);
        let phi = basis(p.tau_s);
        for (r, &i) in used.iter().enumerate() {
            atb[r] += w * phi[i] * p.adev * p.adev;
            for (c, &j) in used.iter().enumerate() {
                ata[(r, c)] += w * phi[i] * phi[j];
            }
        }
    }
    let sol = ata.lu().solve(&atb)?;
    let mut coef = [0.0; 3];
    for (r, &i) in used.iter().enumerate() {
        coef[i] = sol[r];
    }
    coef.iter().all(|c| c.is_finite()).then_some(coef)
}

/// Mean and standard deviation (n − 1) of `samples`; `None` with fewer than two.
pub fn mean_sd(samples: &[f64]) -> Option<(f64, f64)> {
    if samples.len() < 2 {
        return None;
    }
    let n = samples.len() as f64;
    let mean = samples.iter().sum::<f64>() / n;
    let var = samples.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Some((mean, var.sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::gps::SplitMix64;

    fn gauss(r: &mut SplitMix64) -> f64 {
        let u1 = r.next_f64().max(f64::MIN_POSITIVE);
        let u2 = r.next_f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    #[test]
    fn white_noise_alone_gives_its_density_and_no_walk() {
        let mut r = SplitMix64::new(3);
        let x: Vec<f64> = (0..100_000).map(|_| 0.02 * gauss(&mut r)).collect();
        let pts = allan_deviation(&x, 0.01);
        assert!((pts[0].adev / 0.02 - 1.0).abs() < 0.02, "{:?}", pts[0]);
        let t = fit(&pts, 0.01).unwrap();
        assert!((t.white_sd / 0.02 - 1.0).abs() < 0.03, "{t:?}");
        assert!(t.random_walk < 1e-4 && t.bias_instability < 2e-3, "{t:?}");
    }

    #[test]
    fn a_random_walk_is_recovered_beside_the_white_noise() {
        let (sd, k, tau0) = (0.01, 2e-3, 0.01);
        let mut r = SplitMix64::new(11);
        let mut bias = 0.0;
        let x: Vec<f64> = (0..200_000)
            .map(|_| {
                bias += k * f64::sqrt(tau0) * gauss(&mut r);
                bias + sd * gauss(&mut r)
            })
            .collect();
        let t = fit(&allan_deviation(&x, tau0), tau0).unwrap();
        assert!((t.white_sd / sd - 1.0).abs() < 0.05, "{t:?}");
        assert!((t.random_walk / k - 1.0).abs() < 0.2, "{t:?}");
    }

    #[test]
    fn short_or_flat_records_give_no_fit_rather_than_a_panic() {
        assert!(allan_deviation(&[1.0; 5], 0.01).is_empty());
        assert!(fit(&[], 0.01).is_none());
        // A flat record: nothing, or terms of rounding size.
        if let Some(t) = fit(&allan_deviation(&[2.0; 100], 0.01), 0.01) {
            assert!(t.white_sd < 1e-9 && t.random_walk < 1e-9, "{t:?}");
        }
        assert_eq!(mean_sd(&[1.0]), None);
        assert_eq!(mean_sd(&[1.0, 3.0]), Some((2.0, 2f64.sqrt())));
    }
}
