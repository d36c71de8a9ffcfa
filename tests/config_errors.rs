//! A bad configuration is refused by `check-config` and by every command that loads it, with a
//! message naming the file and the key (or the position in a data file) and exit status 2 (a
//! run that fails exits 1); never a panic. So is a bad number on `sim`'s command line.

mod common;
use common::*;
use std::path::Path;

/// Exit status of a refused configuration or command line.
const REFUSED: Option<i32> = Some(2);

/// Runs check-config and replay with the given profile and extra args; both must be refused
/// with a message containing every one of `needles`. Returns check-config's stderr.
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
        assert_eq!(o.status.code(), REFUSED, "{args:?}: {err}");
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
    // The limits the tests give runs on this shared machine stay accepted.
    let mut args = vec!["check-config", "config/uquad.toml"];
    args.extend(REALTIME_TOLERANT);
    let o = uquad(&root(), &args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Values that once passed and would fly unsafely: a mass so light (or a top speed so high)
/// that the slowest motor command is below the ESC start threshold, no settling before the
/// ESC start, an IMU silence of seconds.
#[test]
fn unsafe_values_are_refused_with_their_key() {
    let cases = [
        (
            "vehicle.mass_kg=0.5",
            "vehicle.mass_kg",
            "ESC start threshold",
        ),
        (
            "motor.w_max_rad_s=500",
            "motor.w_max_rad_s",
            "100 to 368.1 rad/s",
        ),
        (
            "imu.settle_frames=0",
            "imu.settle_frames",
            "1 to 10000 frames",
        ),
        (
            "watchdog.imu_timeout_ms=5000",
            "watchdog.imu_timeout_ms",
            "11 to 100 ms",
        ),
    ];
    for (set, key, allowed) in cases {
        let err = refused(
            &root().join("config/uquad.toml"),
            &["--set", set],
            &["uquad.toml", key, "(from --set)", allowed],
        );
        assert!(err.contains("1 problem(s) found"), "{set}: {err}");
    }
}

#[test]
fn the_manual_mass_keys_may_not_reach_a_mass_too_light() {
    refused(
        &profile_2012(),
        &["--set", "control.manual.mass_min_kg=0.5"],
        &[
            "control.manual.mass_min_kg",
            "the lightest mass the manual mass keys reach, 0.5 kg",
            "motor.w_max_rad_s = 368",
            "-18.2 rad/s",
        ],
    );
}

#[test]
fn a_refused_profile_stops_sim_with_status_2() {
    let dir = tempfile::tempdir().unwrap();
    let log_dir = dir.path().to_str().unwrap();
    let o = uquad(
        &root(),
        &[
            "sim",
            "--set",
            "watchdog.sanity_max=10000",
            "--log-dir",
            log_dir,
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), REFUSED, "{err}");
    assert!(
        err.contains("watchdog.sanity_max") && err.contains("1 to 100"),
        "{err}"
    );
}

/// `sim` with a bad number on its command line: refused with status 2, the flag and the
/// value named, before anything runs.
#[test]
fn bad_sim_numbers_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let log_dir = dir.path().to_str().unwrap();
    let cases = [
        ("--duration=-1", "--duration", "-1"),
        ("--duration=nan", "--duration", "nan"),
        ("--duration=0", "--duration", "more than 0, at most 86400 s"),
        ("--inject=imu-stall@1e9", "--inject", "imu-stall@1e9"),
        (
            "--seed=18446744073709551615",
            "--seed",
            "18446744073709551615",
        ),
    ];
    for (arg, flag, value) in cases {
        let o = uquad(&root(), &["sim", arg, "--log-dir", log_dir]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), REFUSED, "{arg}: {err}");
        assert!(err.contains(flag) && err.contains(value), "{arg}: {err}");
        assert!(!err.contains("panicked"), "{arg}: {err}");
    }
    let runs = std::fs::read_dir(dir.path()).map_or(0, |d| d.count());
    assert_eq!(runs, 0, "no run folder is written");
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
fn an_innovation_gate_without_width_is_refused() {
    for (set, value) in [("ekf.gate_sigma=0", "0"), ("ekf.gate_sigma=inf", "inf")] {
        refused(
            &root().join("config/uquad.toml"),
            &["--set", set],
            &[
                "uquad.toml",
                "ekf.gate_sigma",
                &format!("{value} is out of range (from --set)"),
                "more than 0 standard deviations (finite)",
            ],
        );
    }
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
    assert_eq!(o.status.code(), REFUSED);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}

/// The RC receiver's keys: a function on another's channel, a calibration out of order, an
/// RC-loss action that kills, a mode switch of too many positions or an unknown mode, each
/// refused naming its key.
#[test]
fn rc_keys_are_refused_with_their_key() {
    let cases: [(&[&str], &str, &str); 5] = [
        (
            &["rc.yaw.channel=3"],
            "rc.yaw.channel",
            "no other function uses",
        ),
        (&["rc.roll.min=1000"], "rc.roll", "min < center < max"),
        (
            &["failsafe.rc_loss_action=\"kill\""],
            "failsafe.rc_loss_action",
            "\"land\", \"return\" or \"hold\"",
        ),
        (
            &["rc.modes=[\"hold\",\"land\",\"hold\"]"],
            "rc.modes",
            "1 to 6 modes",
        ),
        (
            &["failsafe.rc_timeout_s=0"],
            "failsafe.rc_timeout_s",
            "0.2 to 10 s",
        ),
    ];
    for (sets, key, allowed) in cases {
        let args: Vec<&str> = sets.iter().flat_map(|s| ["--set", s]).collect();
        refused(
            &root().join("config/uquad.toml"),
            &args,
            &["uquad.toml", key, allowed],
        );
    }
    refused(
        &root().join("config/uquad.toml"),
        &["--set", "rc.modes=[\"acro\"]"],
        &["rc.modes", "unknown variant"],
    );
}
