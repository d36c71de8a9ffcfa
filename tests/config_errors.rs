//! A bad configuration is refused by `check-config` and by every command that loads it, with a
//! message naming the file and the key (or the position in a data file); never a panic.

mod common;
use common::*;
use std::path::Path;

/// Runs check-config and replay with the given profile and extra args; both must fail with a
/// message containing every one of `needles`. Returns check-config's stderr.
fn refused(cfg: &Path, extra: &[&str], needles: &[&str]) -> String {
    let cfg = cfg.to_str().unwrap();
    let mut check = vec!["check-config", cfg];
    check.extend_from_slice(extra);
    let out = tempfile::tempdir().unwrap();
    let flight = flight_dir();
    let mut replay = vec![
        "replay",
        flight.to_str().unwrap(),
        "--config",
        cfg,
        "--out",
        out.path().to_str().unwrap(),
    ];
    replay.extend_from_slice(extra);
    let mut first = String::new();
    for args in [check, replay] {
        let o = uquad(&root(), &args);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(!o.status.success(), "{args:?} accepted the configuration");
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        for n in needles {
            assert!(err.contains(n), "{args:?}: {n:?} missing from:\n{err}");
        }
        assert!(
            !out.path().join("kalman_in.log").exists(),
            "nothing is written with a bad configuration"
        );
        if first.is_empty() {
            first = err;
        }
    }
    first
}

#[test]
fn valid_profiles_pass() {
    for cfg in ["config/uquad.toml", "config/flight-2012-05.toml"] {
        let o = uquad(&root(), &["check-config", cfg]);
        assert!(
            o.status.success(),
            "{cfg}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // An override inside the range is accepted.
    let o = uquad(
        &root(),
        &[
            "check-config",
            "config/uquad.toml",
            "--set",
            "vehicle.mass_kg=1.6",
            "--set",
            "gps.mode=off",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn unknown_key_in_file() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    let text = std::fs::read_to_string(&cfg).unwrap();
    std::fs::write(
        &cfg,
        text.replace("[vehicle]\n", "[vehicle]\nmass_lb = 3\n"),
    )
    .unwrap();
    refused(
        &cfg,
        &[],
        &["flight-2012-05.toml", "vehicle.mass_lb", "unknown key"],
    );
}

#[test]
fn unknown_key_through_set() {
    refused(
        &profile_2012(),
        &["--set", "control.hover_height=2"],
        &[
            "flight-2012-05.toml",
            "control.hover_height",
            "unknown key (from --set)",
        ],
    );
}

#[test]
fn out_of_range_mass_through_set() {
    refused(
        &profile_2012(),
        &["--set", "vehicle.mass_kg=-3"],
        &[
            "flight-2012-05.toml",
            "vehicle.mass_kg",
            "-3 is out of range (from --set)",
        ],
    );
}

#[test]
fn out_of_range_observer_and_motor_lag() {
    refused(
        &profile_2012(),
        &[
            "--set",
            "control.torque_observer_s=0.001",
            "--set",
            "motor.tau_s=0",
        ],
        &[
            "control.torque_observer_s",
            "0.001 is out of range",
            "0 (off) or 0.01 to 10 s",
            "motor.tau_s",
            "more than 0, at most 1 s",
        ],
    );
}

#[test]
fn wrong_type_and_bad_enum() {
    refused(
        &profile_2012(),
        &[
            "--set",
            "control.hover_z_m=\"high\"",
            "--set",
            "gps.mode=satellite",
        ],
        &["control.hover_z_m", "gps.mode", "unknown variant"],
    );
}

#[test]
fn missing_calibration_file() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    std::fs::remove_file(dir.path().join("imu_calib.txt")).unwrap();
    refused(
        &cfg,
        &[],
        &[
            "flight-2012-05.toml",
            "imu.calib_file",
            "cannot read",
            "imu_calib.txt",
        ],
    );
}

#[test]
fn malformed_number_in_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    let calib = dir.path().join("imu_calib.txt");
    let text = std::fs::read_to_string(&calib).unwrap();
    std::fs::write(
        &calib,
        text.replacen("16.937408636394", "16.93x408636394", 1),
    )
    .unwrap();
    refused(
        &cfg,
        &[],
        &[
            "imu_calib.txt",
            "imu.calib_file",
            "number 10 (line 4, column 12) is malformed",
            "16.93x408636394",
        ],
    );
}

#[test]
fn short_gain_file() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    std::fs::write(dir.path().join("K_int_full_ppzt.txt"), "1 2 3\n").unwrap();
    refused(
        &cfg,
        &[],
        &[
            "K_int_full_ppzt.txt",
            "control.k_int_file",
            "expected 16 numbers, found 3",
        ],
    );
}

#[test]
fn malformed_toml() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    std::fs::write(&cfg, "[vehicle\nmass_kg = 1\n").unwrap();
    refused(
        &cfg,
        &[],
        &["flight-2012-05.toml", "not valid TOML", "line 1"],
    );
}

#[test]
fn every_problem_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = copy_profile(dir.path());
    std::fs::remove_file(dir.path().join("K_prop_full_ppzt.txt")).unwrap();
    let err = refused(
        &cfg,
        &[
            "--set",
            "vehicle.mass_kg=-3",
            "--set",
            "imu.bogus=1",
            "--set",
            "control.integral.z.cap=0",
            "--set",
            "imu.calib_frames=\"many\"",
        ],
        &[
            "vehicle.mass_kg",
            "imu.bogus",
            "control.integral.z.cap",
            "imu.calib_frames",
            "control.k_prop_file",
        ],
    );
    assert!(err.contains("5 problem(s) found"), "{err}");
}

#[test]
fn default_config_under_working_directory() {
    // replay needs a config: without --config and without RUN_DIR/config.toml it says so.
    let dir = tempfile::tempdir().unwrap();
    let o = uquad(dir.path(), &["check-config", "nope.toml"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}
