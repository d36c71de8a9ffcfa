//! The 15-state EKF on the real 2012-05-25 flight: replay reproduces the original's x_hat.log.

mod common;
use common::*;
use std::path::Path;

/// Largest difference between our x_hat.log and the original's, over every row we wrote.
fn x_hat_error(out: &Path) -> f64 {
    let ours = numbers(&out.join("x_hat.log"));
    let theirs = numbers(&flight_dir().join("x_hat.log"));
    // The original has one row more than its archived logs support: the archiving dropped the
    // last line of imu_raw.log and kalman_in.log, so the input of that last step is gone.
    assert_eq!(theirs.len(), 1121);
    assert_eq!(ours.len(), 1120, "one x_hat row per kalman_in row");
    let mut worst = 0.0f64;
    for (a, b) in ours.iter().zip(&theirs) {
        assert_eq!(a.len(), 15);
        for (x, y) in a.iter().zip(b) {
            worst = worst.max((x - y).abs());
        }
    }
    worst
}

#[test]
fn x_hat_matches_the_original_with_recorded_gps_times() {
    let out = replay_ok(&flight_dir(), &[]);
    let e = x_hat_error(out.path());
    assert!(e <= 1e-6, "largest state difference {e}");
    // A faithful port is at rounding level.
    assert!(e < 1e-12, "largest state difference {e}");
}

#[test]
fn x_hat_matches_the_original_with_generated_fake_gps() {
    // Without gps.log the fake-GPS steps come from the rule of ERRATA 10 on the w.log clock.
    let run = tempfile::tempdir().unwrap();
    for f in ["imu_raw.log", "kalman_in.log", "w.log", "int.log"] {
        std::fs::copy(flight_dir().join(f), run.path().join(f)).unwrap();
    }
    let out = replay_ok(run.path(), &[]);
    let e = x_hat_error(out.path());
    assert!(e < 1e-12, "largest state difference {e}");
}

#[test]
fn gps_updates_matter() {
    // Sanity of the comparison: without GPS updates the estimate leaves the original's.
    let out = replay_ok(&flight_dir(), &["--set", "gps.mode=off"]);
    let e = x_hat_error(out.path());
    assert!(e > 1e-3, "GPS off should change x and y: {e}");
}

#[test]
fn original_model_switch() {
    // The corrected model (cos(phi)cos(psi) in the z row) no longer reproduces the log.
    let out = replay_ok(&flight_dir(), &["--set", "ekf.original_model=false"]);
    let e = x_hat_error(out.path());
    assert!(e > 1e-6, "corrected model should differ: {e}");
    assert!(e < 1.0, "but only slightly: {e}");
    // Only through z and what z feeds: x, y and the attitude barely move.
    let ours = numbers(&out.path().join("x_hat.log"));
    let theirs = numbers(&flight_dir().join("x_hat.log"));
    let z_diff = ours
        .iter()
        .zip(&theirs)
        .map(|(a, b)| (a[2] - b[2]).abs())
        .fold(0.0, f64::max);
    assert!(z_diff > 1e-6, "{z_diff}");
}

#[test]
fn innov_log_has_a_row_per_step_and_the_2012_profile_gates_nothing() {
    let fused = replay_ok(&flight_dir(), &[]);
    let rows = read_table(&fused.path().join("innov.log"));
    assert_eq!(rows.len(), 1120);
    let mut gps_steps = 0;
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 5, "row {}", k + 1);
        assert_eq!(
            r[4],
            "0",
            "row {}: the 2012 profile fuses everything",
            k + 1
        );
        let ratio = |i: usize| r[i].parse::<f64>().unwrap();
        assert!(
            ratio(1).is_finite() && ratio(2).is_finite(),
            "row {}",
            k + 1
        );
        gps_steps += usize::from(r[3] != "nan");
    }
    assert!(gps_steps > 5 && gps_steps < 100, "{gps_steps} GPS steps");
    // A gate far too narrow with gating on leaves groups out, and the estimate changes.
    let narrow = replay_ok(
        &flight_dir(),
        &[
            "--set",
            "ekf.gate_fusion=true",
            "--set",
            "ekf.gate_sigma=0.01",
        ],
    );
    let gated = read_table(&narrow.path().join("innov.log"))
        .iter()
        .filter(|r| r[4] != "0")
        .count();
    assert!(gated > 10, "{gated} steps gated");
    let x_hat = |d: &tempfile::TempDir| std::fs::read(d.path().join("x_hat.log")).unwrap();
    assert_ne!(x_hat(&fused), x_hat(&narrow));
}

#[test]
fn covariance_stays_symmetric_positive_definite() {
    let profile = uquad::config::load(&profile_2012(), &[]).unwrap();
    let out = tempfile::tempdir().unwrap();
    let mut steps = 0;
    let mut worst_asym = 0.0f64;
    uquad::app::replay::run_observed(&flight_dir(), &profile, out.path(), true, |ekf| {
        steps += 1;
        // The model's fifteen states: the gyros' bias states are off in this profile (zero).
        let p = &ekf
            .p
            .fixed_view::<{ uquad::core::ekf::N_MODEL }, { uquad::core::ekf::N_MODEL }>(0, 0)
            .into_owned();
        let asym = (p - p.transpose()).abs().max() / p.abs().max();
        worst_asym = worst_asym.max(asym);
        let sym = (p + p.transpose()) * 0.5;
        assert!(
            sym.cholesky().is_some(),
            "P not positive definite at step {steps}"
        );
    })
    .unwrap();
    assert_eq!(steps, 1120);
    assert!(worst_asym < 1e-9, "relative asymmetry {worst_asym}");
}

#[test]
fn fake_random_is_seeded() {
    let a = replay_ok(
        &flight_dir(),
        &["--set", "gps.mode=fake-random", "--set", "gps.seed=3"],
    );
    let b = replay_ok(
        &flight_dir(),
        &["--set", "gps.mode=fake-random", "--set", "gps.seed=3"],
    );
    let c = replay_ok(
        &flight_dir(),
        &["--set", "gps.mode=fake-random", "--set", "gps.seed=4"],
    );
    let read = |d: &tempfile::TempDir| std::fs::read(d.path().join("x_hat.log")).unwrap();
    assert_eq!(read(&a), read(&b));
    assert_ne!(read(&a), read(&c));
}

#[test]
fn recorded_gpsd_fixes_pull_the_position() {
    // A run folder whose gps.log is in the gpsd client's 15-column format: fixes 20 m north
    // (after the first, which sets the origin) pull the estimate north, not west.
    let run = tempfile::tempdir().unwrap();
    for f in ["imu_raw.log", "kalman_in.log", "w.log", "int.log"] {
        std::fs::copy(flight_dir().join(f), run.path().join(f)).unwrap();
    }
    let mut gps = String::new();
    let north_deg = 20.0 / 110_900.0;
    for k in 0..11 {
        let lat = -34.919588333 + if k == 0 { 0.0 } else { north_deg };
        gps.push_str(&format!(
            "{}.135285\t1327671477.494110\t3\t0\t0\t27.7\t0\t0\t0\t{lat:.9}\t-56.166258333\t0\t0\t0\t1\t\n\r",
            12 + k
        ));
    }
    std::fs::write(run.path().join("gps.log"), gps).unwrap();
    let out = replay_ok(run.path(), &["--set", "gps.mode=gpsd"]);
    let x = numbers(&out.path().join("x_hat.log"));
    let last = x.last().unwrap();
    // Against the same flight with its fixes all at the origin (fake-zero at the same times).
    let base = replay_ok(&flight_dir(), &[]);
    let base = numbers(&base.path().join("x_hat.log"));
    let base = base.last().unwrap();
    let (dx, dy) = (last[0] - base[0], last[1] - base[1]);
    assert!(dx > 5.0, "x (north) {} vs {}", last[0], base[0]);
    // y follows through the filter's velocity coupling only, far less than x.
    assert!(dy.abs() < 0.2 * dx, "y (west) moved {dy} for {dx} north");
    // And a time-only gps.log is refused in gpsd mode with a clear message.
    std::fs::copy(flight_dir().join("gps.log"), run.path().join("gps.log")).unwrap();
    let (o, _) = replay_2012(run.path(), &["--set", "gps.mode=gpsd"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("gps.mode=fake-zero"));
}
