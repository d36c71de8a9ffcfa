//! `uquad noise`: the sensors' noise from a still segment, checked against what the simulator
//! is known to produce (`uquad::sim::imu::expected_frame_sd`) and run on the 2012 flight.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use uquad::core::imu::calib::Calibration;
use uquad::sim::imu::{ImuNoise, expected_frame_sd};

/// A still simulated vehicle: armed on the ground, motors idling, for `duration` s; returns
/// the log folder and the run folder.
fn still_run(duration: &str, sets: &[&str]) -> (tempfile::TempDir, PathBuf) {
    let mut args = vec![
        "--fast",
        "--script",
        "arm@1",
        "--duration",
        duration,
        "--set",
        "commander.disarm_ground_s=600",
    ];
    // The walks this test recovers are a hundred times a real MEMS's, and the accelerometer's
    // has no state in the filter: on this profile's noise values it soon contradicts the fixes
    // (a lost receiver disarms the vehicle, a tumbling estimate halts it); on the 2012
    // flights' wide ones it follows them. The noise is read from the raw frames, not the
    // filter.
    args.extend_from_slice(&EKF_2012);
    for s in sets {
        args.extend_from_slice(&["--set", s]);
    }
    let (status, report, logs) = sim_report(&args);
    assert!(status.success(), "{report}");
    let run = PathBuf::from(report["run_dir"].as_str().unwrap());
    (logs, run)
}

/// `uquad noise ARGS --report`, which must succeed: its report and stdout.
fn noise(args: &[&str]) -> (serde_json::Value, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("noise.json");
    let mut all = vec!["noise"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--report", path.to_str().unwrap()]);
    let o = uquad(&root(), &all);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = std::fs::read_to_string(&path).unwrap();
    (serde_json::from_str(&text).unwrap(), out)
}

fn within(found: f64, want: f64, share: f64, what: &str) {
    assert!(
        (found / want - 1.0).abs() <= share,
        "{what}: found {found:.4e}, the simulator's {want:.4e}"
    );
}

/// The per-frame noise the default profile's simulated IMU produces at rest.
fn expected(sets_walk: bool) -> ([f64; 3], [f64; 3]) {
    expected_at(
        sets_walk,
        [0.0, 0.0, uquad::core::model::GRAVITY_M_S2],
        None,
    )
}

/// The same with every axis far from zero counts.
fn expected_far() -> ([f64; 3], [f64; 3]) {
    expected_at(true, [3.0, 3.0, 13.0], Some([0.3; 3]))
}

fn expected_at(sets_walk: bool, acc: [f64; 3], gyro: Option<[f64; 3]>) -> ([f64; 3], [f64; 3]) {
    let calib = Calibration::parse(include_str!("../config/imu_calib.txt")).unwrap();
    let noise = ImuNoise {
        acc_m_s2: 0.05,
        gyro_rad_s: 0.003,
        gyro_bias_rad_s: [0.01, -0.005, 0.002],
        baro_pa: 1.0,
        mag: 0.005,
        temp_c: 0.0,
        gyro_walk_rad_s_per_sqrt_s: if sets_walk { WALK_GYRO } else { 0.0 },
        acc_walk_m_s2_per_sqrt_s: if sets_walk { WALK_ACC } else { 0.0 },
    };
    let gyro = gyro.unwrap_or(noise.gyro_bias_rad_s);
    expected_frame_sd(&calib, &noise, 30.0, acc, gyro)
}

const WALK_GYRO: f64 = 0.005;
const WALK_ACC: f64 = 0.05;

fn axis(report: &serde_json::Value, sensor: &str, i: usize, key: &str) -> f64 {
    report[sensor][i][key].as_f64().unwrap_or(f64::NAN)
}

#[test]
fn recovers_the_simulated_white_noise_and_barometer() {
    let (_logs, run) = still_run("120", &[]);
    let (r, out) = noise(&[run.to_str().unwrap(), "--from", "10"]);
    assert!(r["frames"].as_u64().unwrap() > 10_000, "{r}");
    let (acc, gyro) = expected(false);
    for i in 0..3 {
        within(axis(&r, "acc", i, "white_sd"), acc[i], 0.10, "acc");
        within(axis(&r, "gyro", i, "white_sd"), gyro[i], 0.10, "gyro");
    }
    // 1 Pa per reading, rounded to a pascal: √(1 + 1/12).
    let baro = r["baro_pa"]["sd"].as_f64().unwrap();
    within(baro, (1.0f64 + 1.0 / 12.0).sqrt(), 0.10, "barometer");
    // The Allan curve in the report: white noise falls as 1/√τ from the per-frame figure.
    let curve: Vec<[f64; 2]> = serde_json::from_value(r["gyro"][0]["allan"].clone()).unwrap();
    assert!(curve.len() > 20, "{curve:?}");
    within(curve[0][1], gyro[0], 0.10, "the curve's first point");
    let (a, b) = (curve[0], curve[10]);
    within(b[1] / a[1], (a[0] / b[0]).sqrt(), 0.15, "the curve's slope");
    // The R it implies has the gyro rows at their white noise squared.
    let r_imu: Vec<f64> = serde_json::from_value(r["r_imu"].clone()).unwrap();
    within(r_imu[6], gyro[0].powi(2), 0.21, "r_imu wx");
    assert!(out.contains("implied ekf.r_imu"), "{out}");
}

#[test]
fn recovers_the_simulated_bias_random_walk() {
    let walk_gyro = format!("sim.gyro_bias_walk_rad_s_per_sqrt_s={WALK_GYRO}");
    let walk_acc = format!("sim.acc_bias_walk_m_s2_per_sqrt_s={WALK_ACC}");
    for seed in ["1", "2"] {
        let seed_set = format!("sim.seed={seed}");
        let (_logs, run) = still_run("620", &[&walk_gyro, &walk_acc, &seed_set]);
        let (r, _) = noise(&[run.to_str().unwrap(), "--from", "10"]);
        // The walks carry each axis far from zero counts, where the halving's dead zone no
        // longer narrows the noise: the per-frame figure away from it.
        let (acc, gyro) = expected_far();
        for i in 0..3 {
            within(
                axis(&r, "acc", i, "random_walk"),
                WALK_ACC,
                0.10,
                "acc walk",
            );
            within(
                axis(&r, "gyro", i, "random_walk"),
                WALK_GYRO,
                0.10,
                "gyro walk",
            );
            within(axis(&r, "acc", i, "white_sd"), acc[i], 0.10, "acc");
            within(axis(&r, "gyro", i, "white_sd"), gyro[i], 0.10, "gyro");
        }
    }
}

#[test]
fn reads_the_2012_calibration_segment_and_says_it_is_short() {
    let data = root().join("tests/data/flight-2012-05-25");
    let calib = root().join("config/imu_calib.txt");
    let (r, out) = noise(&[
        data.to_str().unwrap(),
        "--calib",
        calib.to_str().unwrap(),
        "--to",
        "12.12",
    ]);
    // The 2012 calibration: the first 512 frames, motors idling (the first at 7.04 s).
    assert_eq!(r["frames"].as_u64(), Some(511), "{r}");
    assert!(out.contains("the segment lasts 5.1 s"), "{out}");
    // The idling motors' vibration: far above the simulator's still IMU.
    let (_, gyro) = expected(false);
    assert!(axis(&r, "gyro", 0, "white_sd") > 5.0 * gyro[0], "{r}");
}

#[test]
fn a_missing_calibration_or_a_short_segment_is_named() {
    let data = root().join("tests/data/flight-2012-05-25");
    let o = uquad(&root(), &["noise", data.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("imu_calib.txt"),
        "{err}"
    );
    assert!(err.contains("--calib"), "{err}");
    let calib = root().join("config/imu_calib.txt");
    let args = [
        "noise",
        data.to_str().unwrap(),
        "--calib",
        calib.to_str().unwrap(),
        "--from",
        "8",
        "--to",
        "8.5",
    ];
    let o = uquad(Path::new(&root()), &args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("at least 100"), "{err}");
}

#[test]
fn a_failed_barometer_is_left_out_of_its_spread_and_named() {
    let (status, report, _logs) = sim_report(&[
        "--fast",
        "--script",
        "arm@7",
        "--duration",
        "40",
        "--set",
        "commander.disarm_ground_s=600",
        "--inject",
        "baro-fail@30",
    ]);
    let run = report["run_dir"].as_str().unwrap().to_string();
    assert!(report["touchdown"].is_null(), "{status}: {report}");
    let (r, out) = noise(&[&run, "--from", "10"]);
    assert!(
        r["baro_alt_m"]["sd"].as_f64().is_some_and(f64::is_finite),
        "{r}"
    );
    assert!(out.contains("gave no barometer altitude"), "{out}");
}
