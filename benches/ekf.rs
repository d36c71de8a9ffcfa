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

criterion_group!(benches, bench_step);
criterion_main!(benches);
