//! The arithmetic of one EKF step, shaped by what is known before the flight: the covariance
//! propagation through the Jacobian's fixed structure, and the measurement update's
//! factorisation. Every loop runs over contiguous columns of column-major storage with lengths
//! fixed at compile time, so the compiler unrolls and vectorises them; nothing is allocated and
//! no matrix is scanned or copied whole.

use nalgebra::{SMatrix, SVector};

/// The filter's state count (spec 3.1's fifteen, then the gyros' bias, then the receiver's
/// horizontal bias) and its covariance's type; `ekf` re-exports both.
pub const N_STATES: usize = 20;
pub type StateMatrix = SMatrix<f64, N_STATES, N_STATES>;

/// The columns of the non-zero entries of D = F − I in each row: the structure of the
/// Jacobian of spec 3.4 (both models), then the gyros' bias (columns 15–17), which enters
/// wherever the body rates do (`ekf_gyro_bias`), then the receiver's bias (rows and columns
/// 18–19), which nothing drives (its decay is applied apart, `ekf_gps_bias`). Position
/// (x, y, z) drives no state, and the yaw rate, the accelerometer's states and the biases
/// (rows 11–19) have no state-dependent terms. A test checks that the filter's Jacobian
/// writes nothing outside it.
pub const D_COLS: [&[usize]; N_STATES] = [
    &[3, 4, 5, 6, 7, 8],
    &[3, 4, 5, 6, 7, 8],
    &[3, 4, 6, 7, 8],
    &[3, 4, 9, 10, 11, 15, 16, 17],
    &[3, 10, 11, 16, 17],
    &[3, 4, 10, 11, 16, 17],
    &[4, 7, 8, 10, 11, 12, 16, 17],
    &[3, 4, 6, 8, 9, 11, 13, 15, 17],
    &[3, 4, 6, 7, 9, 10, 14, 15, 16],
    &[10, 11, 16, 17],
    &[9, 11, 15, 17],
    &[],
    &[],
    &[],
    &[],
    &[],
    &[],
    &[],
    &[],
    &[],
];

/// y += a·x, over a length known at compile time (unrolled and vectorised).
fn axpy<const N: usize>(y: &mut [f64; N], a: f64, x: &[f64; N]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

/// D[i][j] = F[i][j] − δᵢⱼ.
fn d_entry(f: &StateMatrix, i: usize, j: usize) -> f64 {
    f[(i, j)] - if i == j { 1.0 } else { 0.0 }
}

/// Column `I` of Y·Fᵀ, from row `FROM` down: Y's column I plus Σⱼ D[I][j]·(Y's column j) over
/// the listed j. `I` and `FROM` are constants, so the listed columns and the run's length are
/// known when this is compiled: the loops unroll into straight-line vector code.
#[inline(always)]
fn column_of_times_ft<const I: usize, const FROM: usize>(
    f: &StateMatrix,
    y: &[[f64; N_STATES]; N_STATES],
    out: &mut [f64; N_STATES],
) {
    *out = y[I];
    for &j in D_COLS[I] {
        let d = d_entry(f, I, j);
        for (o, y_rj) in out[FROM..].iter_mut().zip(&y[j][FROM..]) {
            *o += d * y_rj;
        }
    }
}

/// Runs `$body` once for each state index as a constant `$i` (one copy of the code per row).
macro_rules! for_each_state {
    ($i:ident => $body:block) => {
        for_each_state!(@ $i $body; 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19)
    };
    (@ $i:ident $body:block; $($n:literal)*) => {{
        $({
            const $i: usize = $n;
            $body
        })*
    }};
}

/// P ← F·P·Fᵀ for a symmetric P, using the fixed structure of F = I + D (`D_COLS`, 70
/// entries); see `propagate_covariance_portable`.
pub fn propagate_covariance(f: &StateMatrix, p: &mut StateMatrix) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { avx::propagate_covariance(f, p) };
    }
    propagate_covariance_portable(f, p)
}

/// P ← F·P·Fᵀ for a symmetric P, using the fixed structure of F = I + D (`D_COLS`, 70
/// entries). With G = P·Fᵀ, whose column i is P's column i plus Σⱼ Dᵢⱼ·(P's column j), and
/// Gᵀ = F·P (P symmetric), F·P·Fᵀ = Gᵀ·Fᵀ is the same column operation on Gᵀ. Only the lower
/// triangle of the result is computed; it is mirrored, so P stays exactly symmetric.
#[inline(always)]
fn propagate_covariance_portable(f: &StateMatrix, p: &mut StateMatrix) {
    let mut g = [[0.0; N_STATES]; N_STATES];
    for_each_state!(I => {
        column_of_times_ft::<I, 0>(f, &p.data.0, &mut g[I]);
    });
    // Gᵀ written column after column, so that the second pass's vector loads do not wait on
    // scalar stores still in flight.
    let gt = transpose(&g);
    for_each_state!(I => {
        let mut col = [0.0; N_STATES];
        column_of_times_ft::<I, I>(f, &gt, &mut col);
        p.data.0[I][I..].copy_from_slice(&col[I..]);
    });
    mirror_lower(p);
}

/// The transpose of a square array of columns, written one column at a time.
#[inline(always)]
fn transpose(a: &[[f64; N_STATES]; N_STATES]) -> [[f64; N_STATES]; N_STATES] {
    let mut t = [[0.0; N_STATES]; N_STATES];
    for (c, t_col) in t.iter_mut().enumerate() {
        for (r, v) in t_col.iter_mut().enumerate() {
            *v = a[r][c];
        }
    }
    t
}

/// Copies the lower triangle onto the upper one, one column at a time.
#[inline(always)]
fn mirror_lower(p: &mut StateMatrix) {
    for c in 1..N_STATES {
        for r in 0..c {
            p.data.0[c][r] = p.data.0[r][c];
        }
    }
}

/// Overwrites the lower triangle of S with its Cholesky factor L, S = L·Lᵀ (left-looking,
/// column by column; the strict upper triangle is left as it was), and returns the reciprocals
/// of L's diagonal, which the solves multiply by (a division costs several products' time, and
/// the solves' divisions would sit on their dependency chains); `None` when S is not positive
/// definite (a pivot not above 0, or not a number).
pub fn cholesky_in_place<const M: usize>(s: &mut SMatrix<f64, M, M>) -> Option<[f64; M]> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { avx::cholesky_in_place(s) };
    }
    cholesky_in_place_portable(s)
}

/// [`cholesky_in_place`] in portable code.
#[inline(always)]
fn cholesky_in_place_portable<const M: usize>(l: &mut SMatrix<f64, M, M>) -> Option<[f64; M]> {
    let mut inv_diag = [0.0; M];
    for j in 0..M {
        // Column j is still S's; the columns before it are already L's.
        let mut col = l.data.0[j];
        for k in 0..j {
            axpy(&mut col, -l.data.0[k][j], &l.data.0[k]);
        }
        let pivot = col[j];
        if pivot <= 0.0 || pivot.is_nan() {
            return None;
        }
        let diag = pivot.sqrt();
        inv_diag[j] = 1.0 / diag;
        l.data.0[j][j] = diag;
        for (l_ij, c) in l.data.0[j][j + 1..].iter_mut().zip(&col[j + 1..]) {
            *l_ij = c * inv_diag[j];
        }
    }
    Some(inv_diag)
}

/// Overwrites B with U, U·Lᵀ = B for a lower-triangular L (U = B·L⁻ᵀ); see
/// `solve_right_lower_t_portable`.
pub fn solve_right_lower_t<const M: usize>(
    b: &mut SMatrix<f64, N_STATES, M>,
    l: &SMatrix<f64, M, M>,
    inv_diag: &[f64; M],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { avx::solve_right_lower_t(b, l, inv_diag) };
    }
    solve_right_lower_t_portable(b, l, inv_diag)
}

/// Overwrites B with U, U·Lᵀ = B for a lower-triangular L (U = B·L⁻ᵀ), one column at a time:
/// column k is B's column k less Σ_{m<k} L[k][m]·(U's column m), over L[k][k] (`inv_diag`:
/// 1/L[k][k]).
#[inline(always)]
fn solve_right_lower_t_portable<const M: usize>(
    u: &mut SMatrix<f64, N_STATES, M>,
    l: &SMatrix<f64, M, M>,
    inv_diag: &[f64; M],
) {
    for (k, inv) in inv_diag.iter().enumerate() {
        let mut col = u.data.0[k];
        for m in 0..k {
            axpy(&mut col, -l.data.0[m][k], &u.data.0[m]);
        }
        u.data.0[k] = col.map(|v| v * inv);
    }
}

/// a with L·a = y for a lower-triangular L (forward substitution; `inv_diag`: 1/L[k][k]).
pub fn solve_lower<const M: usize>(
    l: &SMatrix<f64, M, M>,
    inv_diag: &[f64; M],
    y: &SVector<f64, M>,
) -> SVector<f64, M> {
    let mut a = *y;
    for k in 0..M {
        let mut v = a[k];
        for m in 0..k {
            v -= l.data.0[m][k] * a[m];
        }
        a[k] = v * inv_diag[k];
    }
    a
}

/// x += U·a.
pub fn add_product<const M: usize>(
    x: &mut SVector<f64, N_STATES>,
    u: &SMatrix<f64, N_STATES, M>,
    a: &SVector<f64, M>,
) {
    let mut sum = [0.0; N_STATES];
    for k in 0..M {
        axpy(&mut sum, a[k], &u.data.0[k]);
    }
    for (x, s) in x.iter_mut().zip(sum) {
        *x += s;
    }
}

/// P −= U·Uᵀ for a symmetric P; see `subtract_gram_portable`.
pub fn subtract_gram<const M: usize>(p: &mut StateMatrix, u: &SMatrix<f64, N_STATES, M>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { avx::subtract_gram(p, u) };
    }
    subtract_gram_portable(p, u)
}

/// P −= U·Uᵀ for a symmetric P: the lower triangle, column by column (each column's run a
/// constant length), mirrored.
#[inline(always)]
fn subtract_gram_portable<const M: usize>(p: &mut StateMatrix, u: &SMatrix<f64, N_STATES, M>) {
    for_each_state!(C => {
        let mut sum = [0.0; N_STATES];
        for u_k in &u.data.0 {
            let u_ck = u_k[C];
            for (s, u_rk) in sum[C..].iter_mut().zip(&u_k[C..]) {
                *s += u_ck * u_rk;
            }
        }
        for (m, v) in p.data.0[C][C..].iter_mut().zip(&sum[C..]) {
            *m -= v;
        }
    });
    mirror_lower(p);
}

/// The heavy kernels compiled for AVX's four-wide registers, chosen at run time when the
/// processor has them. Each lane does the same multiplications and additions in the same order
/// as the portable code (Rust never fuses or reorders floating-point operations), so the results
/// are the same to the bit; a test checks it.
#[cfg(target_arch = "x86_64")]
mod avx {
    use super::*;

    #[target_feature(enable = "avx")]
    pub fn propagate_covariance(f: &StateMatrix, p: &mut StateMatrix) {
        propagate_covariance_portable(f, p)
    }

    #[target_feature(enable = "avx")]
    pub fn cholesky_in_place<const M: usize>(s: &mut SMatrix<f64, M, M>) -> Option<[f64; M]> {
        cholesky_in_place_portable(s)
    }

    #[target_feature(enable = "avx")]
    pub fn solve_right_lower_t<const M: usize>(
        b: &mut SMatrix<f64, N_STATES, M>,
        l: &SMatrix<f64, M, M>,
        inv_diag: &[f64; M],
    ) {
        solve_right_lower_t_portable(b, l, inv_diag)
    }

    #[target_feature(enable = "avx")]
    pub fn subtract_gram<const M: usize>(p: &mut StateMatrix, u: &SMatrix<f64, N_STATES, M>) {
        subtract_gram_portable(p, u)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spd<const M: usize>(seed: usize) -> SMatrix<f64, M, M> {
        let a = SMatrix::<f64, M, M>::from_fn(|i, j| ((i * 7 + j * 3 + seed) % 11) as f64 - 5.0);
        a * a.transpose() + SMatrix::<f64, M, M>::identity()
    }

    /// Whichever code the processor runs, the bits are those of the portable code.
    #[test]
    fn dispatched_kernels_equal_the_portable_ones_to_the_bit() {
        let f = StateMatrix::from_fn(|i, j| {
            let d = if D_COLS[i].contains(&j) {
                0.01 * (i + 2 * j) as f64 - 0.07
            } else {
                0.0
            };
            d + if i == j { 1.0 } else { 0.0 }
        });
        let p0 = spd::<N_STATES>(4) * 1e-3;
        let (mut a, mut b) = (p0, p0);
        propagate_covariance(&f, &mut a);
        propagate_covariance_portable(&f, &mut b);
        assert_eq!(a, b);
        let (mut l, mut l_portable) = (spd::<10>(5), spd::<10>(5));
        let inv = cholesky_in_place(&mut l).unwrap_or_else(|| panic!("not SPD"));
        assert_eq!(Some(inv), cholesky_in_place_portable(&mut l_portable));
        assert_eq!(l, l_portable);
        let mut u = SMatrix::<f64, N_STATES, 10>::from_fn(|i, j| (i * 3 + j) as f64 * 0.1 - 1.3);
        let mut u_portable = u;
        solve_right_lower_t(&mut u, &l, &inv);
        solve_right_lower_t_portable(&mut u_portable, &l, &inv);
        assert_eq!(u, u_portable);
        subtract_gram(&mut a, &u);
        subtract_gram_portable(&mut b, &u);
        assert_eq!(a, b);
    }

    #[test]
    fn cholesky_equals_nalgebra_and_refuses_what_is_not_positive_definite() {
        let s = spd::<10>(1);
        let mut ours = s;
        let inv = cholesky_in_place(&mut ours).unwrap_or_else(|| panic!("S is positive definite"));
        let ours = ours.lower_triangle();
        assert!((0..10).all(|i| (inv[i] * ours[(i, i)] - 1.0).abs() < 1e-15));
        let theirs = s
            .cholesky()
            .map(|c| c.l())
            .unwrap_or_else(|| panic!("nalgebra"));
        assert!((ours - theirs).abs().max() < 1e-12 * theirs.abs().max());
        for bad_pivot in [-1.0, f64::NAN] {
            let mut bad = s;
            bad[(4, 4)] = bad_pivot;
            assert!(cholesky_in_place(&mut bad).is_none());
        }
    }

    #[test]
    fn triangular_solves_invert_their_products() {
        let mut l = spd::<10>(2);
        let inv = cholesky_in_place(&mut l).unwrap_or_else(|| panic!("not SPD"));
        let l = l.lower_triangle();
        let b = SMatrix::<f64, N_STATES, 10>::from_fn(|i, j| (i as f64 - 7.0) * 0.3 + j as f64);
        let mut u = b;
        solve_right_lower_t(&mut u, &l, &inv);
        assert!((u * l.transpose() - b).abs().max() < 1e-12 * b.abs().max());
        let y = SVector::<f64, 10>::from_fn(|i, _| i as f64 - 4.5);
        let a = solve_lower(&l, &inv, &y);
        assert!((l * a - y).abs().max() < 1e-12);
    }

    #[test]
    fn products_equal_the_dense_ones() {
        let u = SMatrix::<f64, N_STATES, 12>::from_fn(|i, j| ((i * 5 + j) % 7) as f64 - 3.0);
        let a = SVector::<f64, 12>::from_fn(|i, _| 0.5 * i as f64 - 2.0);
        let mut x = SVector::<f64, N_STATES>::from_fn(|i, _| i as f64);
        let expected = x + u * a;
        add_product(&mut x, &u, &a);
        assert_eq!(x, expected);
        let mut p = spd::<N_STATES>(3);
        let expected = p - u * u.transpose();
        subtract_gram(&mut p, &u);
        assert!((p - expected).abs().max() < 1e-12 * expected.abs().max());
        assert_eq!(p, p.transpose());
    }
}
