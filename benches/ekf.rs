//! One EKF step (predict + 10-row IMU update) and one with the 12-row GPS update.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use uquad::core::ekf::{Ekf, EkfParams, StepInput};
use uquad::core::imu::calib::ImuSample;
use uquad::core::model::w_hover_rad_s;

fn bench_step(c: &mut Criterion) {
    let null = ImuSample {
        acc_m_s2: [-0.23, -0.017, 9.89],
        euler_rad: [-0.0017, 0.0237, 1.9735],
        temp_c: 38.4,
        ..ImuSample::default()
    };
    let mut sample = null;
    sample.gyro_rad_s = [0.01, -0.02, 0.003];
    sample.alt_m = 0.1;
    let w = w_hover_rad_s(1.55);
    let mut input = StepInput {
        u_rad_s: [w + 3.0, w - 2.0, w + 1.0, w],
        mass_kg: 1.55,
        dt_us: 10_000,
        gps: None,
        ground_m: None,
        at_rest: false,
    };
    // Each iteration starts from the same state, so the filter cannot drift into an
    // unrepresentative (diverged or refused) regime over millions of iterations.
    let start = Ekf::new(EkfParams::flight_2012(), &null);
    let mut ekf = start.clone();
    c.bench_function("ekf_step_imu_10_rows", |b| {
        b.iter(|| {
            ekf.x = start.x;
            ekf.p = start.p;
            let (_, r) = ekf.step(black_box(&sample), black_box(&input));
            assert!(r.is_ok());
            black_box(&ekf.x);
        })
    });
    input.gps = Some(uquad::core::gps::GpsSample::at([0.0; 3]));
    c.bench_function("ekf_step_gps_12_rows", |b| {
        b.iter(|| {
            ekf.x = start.x;
            ekf.p = start.p;
            let (_, r) = ekf.step(black_box(&sample), black_box(&input));
            assert!(r.is_ok());
            black_box(&ekf.x);
        })
    });
}

/// The step's two halves on their own: the covariance propagation through F's fixed structure
/// and the update's P −= U·Uᵀ.
fn bench_kernels(c: &mut Criterion) {
    use uquad::core::ekf::{N_STATES, StateMatrix, jacobian};
    use uquad::core::ekf_kernels::{propagate_covariance, subtract_gram};
    let x = uquad::core::ekf::State::from_fn(|i, _| 0.05 * i as f64 - 0.3);
    // The filter's F, the gyros' bias states on (the default profile's).
    let mut params = EkfParams::flight_2012();
    params.gyro_bias_q = 1e-7;
    let ekf = Ekf::new(params, &Default::default());
    let f = ekf.filter_jacobian(&jacobian(&x, &[300.0, 310.0, 295.0, 305.0], 0.01, true));
    let a = StateMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let p0 = a * a.transpose() * 1e-2 + StateMatrix::identity();
    let mut p = p0;
    c.bench_function("ekf_propagate_covariance", |b| {
        b.iter(|| {
            p = p0;
            propagate_covariance(black_box(&f), &mut p);
            black_box(&p);
        })
    });
    let u = nalgebra::SMatrix::<f64, N_STATES, 10>::from_fn(|i, j| 0.01 * ((i * 5 + j) % 7) as f64);
    c.bench_function("ekf_subtract_gram_10_rows", |b| {
        b.iter(|| {
            p = p0;
            subtract_gram(&mut p, black_box(&u));
            black_box(&p);
        })
    });
}

criterion_group!(benches, bench_step, bench_kernels);
criterion_main!(benches);
