//! `uquad sim --inject FAULT@T` on the simulated clock: the watchdog's halts and what keeps
//! flying.

mod common;
use common::*;

/// Runs the sim on the default profile, armed at 7 s and taking off at 10 s (at 1 s and 9 s
/// when calibrated after the arm), never landing, and returns its report (and the folder
/// holding its run, kept while in use).
fn sim_report(args: &[&str]) -> (serde_json::Value, tempfile::TempDir) {
    let mut all = vec!["--fast", "--config", "config/uquad.toml"];
    let script = if args.contains(&AFTER_ARM) {
        HOVER_SCRIPT_AFTER_ARM
    } else {
        HOVER_SCRIPT
    };
    all.extend_from_slice(&["--script", script]);
    all.extend_from_slice(args);
    let (status, r, logs) = common::sim_report(&all);
    // A halt makes the command fail (motors stopped); the report is written either way.
    assert_eq!(status.success(), r["halt"].is_null(), "{r}");
    (r, logs)
}

/// A 60-second flight in which m0 loses 30 % of its thrust at 32 s (inside the hover window,
/// which opens 20 s after the flight ramp: 31 s), with `extra` arguments.
fn thrust_loss_report(extra: &[&str]) -> (serde_json::Value, tempfile::TempDir) {
    // Exact fixes: the figures are the control's, not the receiver's error.
    let mut args = vec!["--duration", "60", "--inject", "thrust-loss@32"];
    args.extend_from_slice(&EXACT_GPS);
    args.extend_from_slice(extra);
    sim_report(&args)
}

/// Every simulated ESC ends disabled, its last two acknowledged writes a zero speed, then the
/// disable.
fn assert_escs_end_zero_then_disable(r: &serde_json::Value) {
    let escs = r["esc_end"]
        .as_array()
        .unwrap_or_else(|| panic!("no esc_end: {r}"));
    assert_eq!(escs.len(), 4, "{r}");
    for e in escs {
        assert_eq!(e["enabled"], false, "{e}");
        assert_eq!(
            e["last_writes"],
            serde_json::json!(["speed 0", "disable"]),
            "{e}"
        );
    }
}

/// The err.log of a run.
fn err_log(r: &serde_json::Value) -> String {
    std::fs::read_to_string(std::path::Path::new(r["run_dir"].as_str().unwrap()).join("err.log"))
        .unwrap()
}

#[test]
fn imu_stall_halts_within_14_ms_of_the_last_frame() {
    let (r, _logs) = sim_report(&["--duration", "40", "--inject", "imu-stall@30"]);
    assert_eq!(r["halt"]["reason"], "imu-timeout", "{r}");
    let ms = r["halt"]["latency_ms"].as_f64().unwrap();
    assert!(ms <= 14.0, "{ms} ms");
    // The last frame was just before 30 s.
    assert!(
        (r["halt"]["event_s"].as_f64().unwrap() - 29.99).abs() < 0.011,
        "{r}"
    );
    assert_eq!(r["watchdog_trips"], 1);
    assert_eq!(r["halt"]["confirmed"], true, "{r}");
    assert_escs_end_zero_then_disable(&r);
}

#[test]
fn imu_stall_halts_in_every_start_up_phase_with_the_motors_enabled() {
    // The start-up calibrated after the arm (the original's order; calibrated at rest the
    // motors are off until the arm) on the simulated clock with `arm@1,takeoff@9`: settled
    // at about 0.5 s, ESC ramp from 1.0 s to 3.4 s, calibration to about 8.5 s, idling, then
    // the takeoff's flight ramp (100 steps) from 9 s to 10 s. Each phase is told by err.log.
    let phases = [
        ("1.5", "ESC start-up ramp", "ESC ramp done"),
        ("5", "ESC ramp done", "IMU calibration completed"),
        ("9.5", "mode takeoff: command takeoff", "mode hold"),
    ];
    for (at, reached, not_reached) in phases {
        let stall = format!("imu-stall@{at}");
        let args = ["--duration", "20", "--inject", &stall, "--set", AFTER_ARM];
        let (r, _logs) = sim_report(&args);
        assert_eq!(r["halt"]["reason"], "imu-timeout", "{stall}: {r}");
        let last_frame_s = r["halt"]["event_s"].as_f64().unwrap();
        let at_s: f64 = at.parse().unwrap();
        assert!(
            (last_frame_s - (at_s - 0.01)).abs() < 0.0011,
            "{stall}: {r}"
        );
        let ms = r["halt"]["latency_ms"].as_f64().unwrap();
        assert!(ms <= 14.0, "{stall}: {ms} ms after the last frame");
        assert_eq!(r["halt"]["confirmed"], true, "{stall}: {r}");
        assert_escs_end_zero_then_disable(&r);
        let err = err_log(&r);
        assert!(err.contains(reached), "{stall}: {err}");
        assert!(!err.contains(not_reached), "{stall}: {err}");
        assert!(
            r["simulated_s"].as_f64().unwrap() < at_s + 0.1,
            "the run ended: {r}"
        );
    }
}

#[test]
fn esc_nack_halts_within_12_ms_and_names_the_escs_that_never_confirmed() {
    let (r, _logs) = sim_report(&["--duration", "40", "--inject", "esc-nack@30"]);
    assert_eq!(r["halt"]["reason"], "esc-ack", "{r}");
    let ms = r["halt"]["decision_ms"].as_f64().unwrap();
    assert!(ms <= 12.0, "decided {ms} ms after the first failed write");
    assert!(r["esc"]["failed_writes"].as_u64().unwrap() >= 12, "{r}");
    // The refusals never end: the stop is retried for watchdog.halt_retry_ms (500 ms), then
    // reported unconfirmed by every ESC.
    assert_eq!(r["halt"]["confirmed"], false, "{r}");
    assert_eq!(
        r["halt"]["unconfirmed"],
        serde_json::json!(["0x69", "0x6b", "0x6a", "0x68"]),
        "{r}"
    );
    let retried_ms = r["halt"]["latency_ms"].as_f64().unwrap() - ms;
    assert!(
        (499.0..=501.0).contains(&retried_ms),
        "retried {retried_ms} ms: {r}"
    );
    let err = err_log(&r);
    assert!(
        err.contains("stop NOT confirmed by 0x69, 0x6b, 0x6a, 0x68"),
        "{err}"
    );
}

#[test]
fn a_lost_barometer_lands_on_what_is_left() {
    // The barometer reads 0 Pa from 30 s: no altitude. The attitude is still there, so no
    // halt: silent for half a second, the barometer is lost, and the `estimator` failsafe
    // lands at once (not failsafe.ekf_bad_s later) on the fixes' vertical velocity and the
    // accelerometer; the touchdown disarms.
    let (r, _logs) = sim_report(&["--inject", "baro-fail@30"]);
    assert!(r["halt"].is_null(), "{r}");
    let fs = &r["failsafes"][0];
    assert_eq!(fs["kind"], "estimator", "{r}");
    assert_eq!(fs["action"], "land", "{r}");
    let fs_s = fs["t_s"].as_f64().unwrap();
    assert!((30.5..=30.6).contains(&fs_s), "failsafe at {fs_s} s: {r}");
    let modes = r["modes"].as_array().unwrap();
    assert_eq!(modes.last().unwrap()["mode"], "disarmed", "{r}");
    assert_eq!(modes.last().unwrap()["why"], "touchdown", "{r}");
    let v = r["touchdown"]["v_m_s"].as_f64().unwrap();
    assert!(v <= 0.5, "touchdown at {v} m/s: {r}");
    for c in r["safety"]["contacts"].as_array().unwrap() {
        assert!(c["v_m_s"].as_f64().unwrap() <= 0.5, "{r}");
    }
    assert!(r["ekf_gated"]["altitude"].as_u64().unwrap() > 0, "{r}");
    assert_escs_end_zero_then_disable(&r);
}

#[test]
fn garbage_on_the_imu_wire_halts_as_a_silent_imu() {
    let (r, _logs) = sim_report(&["--duration", "40", "--inject", "imu-garbage@30"]);
    assert_eq!(r["halt"]["reason"], "imu-timeout", "{r}");
    assert!(r["halt"]["latency_ms"].as_f64().unwrap() <= 14.0, "{r}");
    assert!(r["imu"]["discarded_bytes"].as_u64().unwrap() > 0, "{r}");
    assert_escs_end_zero_then_disable(&r);
}

#[test]
fn a_stuck_gyro_is_seen_within_five_frames_and_lands() {
    // The gyro repeats its reading from 30 s. Its counts never repeat on a live sensor
    // (core::imu::health): five identical frames mark it lost, its rows leave the filter, the
    // `estimator` failsafe lands at once, at the landing's full speed (the attitude is then
    // the model's guess, good for seconds).
    let (r, _logs) = sim_report(&["--duration", "40", "--inject", "gyro-stuck@30"]);
    assert!(r["halt"].is_null(), "{r}");
    let fs = &r["failsafes"][0];
    assert_eq!(
        (&fs["kind"], &fs["action"]),
        (&"estimator".into(), &"land".into()),
        "{r}"
    );
    let seen_s = fs["t_s"].as_f64().unwrap();
    assert!((30.04..=30.1).contains(&seen_s), "seen at {seen_s} s: {r}");
    let modes = r["modes"].as_array().unwrap();
    assert_eq!(modes.last().unwrap()["why"], "touchdown", "{r}");
    // Down within 2.5 s, its attitude the model's: a firm contact at the landing's own speed
    // (seeds 1-10: at most 0.55 m/s, four of ten under 0.01), never a fall.
    for c in r["safety"]["contacts"].as_array().unwrap() {
        assert!(c["v_m_s"].as_f64().unwrap() <= 2.0, "{r}");
    }
    let run = std::path::Path::new(r["run_dir"].as_str().unwrap());
    let err = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(
        err.contains("gyro stuck: its counts repeated for 5 frames"),
        "{err}"
    );
    assert_escs_end_zero_then_disable(&r);
}

#[test]
fn gps_loss_keeps_hovering_on_the_barometer() {
    // The loss at 30 s, the hover window from 30 s to 60 s: 30 s without GPS. The failsafe's
    // action is set to hold (the default lands; tests/commander.rs).
    let (r, _logs) = sim_report(&[
        "--duration",
        "60",
        "--inject",
        "gps-loss@30",
        "--set",
        "failsafe.gps_loss_action=hold",
    ]);
    assert!(r["halt"].is_null(), "{r}");
    let rms = r["alt_rms_m"].as_f64().unwrap();
    assert!(rms <= 0.2, "altitude RMS {rms} m");
    assert!(r["hover_samples"].as_u64().unwrap() >= 2_900);
    // Without fixes the horizontal position is let go (the filter's x, y drift) and said so.
    let err = std::fs::read_to_string(
        std::path::Path::new(r["run_dir"].as_str().unwrap()).join("err.log"),
    )
    .unwrap();
    assert!(err.contains("position hold on"), "{err}");
    assert!(
        err.contains("position hold off: no GPS fix fused for 3 s"),
        "{err}"
    );
}

#[test]
fn log_stall_costs_no_deadline() {
    let (r, _logs) = sim_report(&[
        "--duration",
        "40",
        "--inject",
        "log-stall@30",
        "--set",
        "log.queue_records=16",
    ]);
    assert!(r["halt"].is_null(), "{r}");
    assert_eq!(r["deadline_misses"], 0);
    // 500 ms of records with a 16-record queue: 34 of x_hat's 50 dropped and counted.
    assert_eq!(r["log_drops"], 34, "{r}");
    assert_eq!(r["log_drops_by_stream"]["x_hat"], 34);
}

#[test]
fn thrust_loss_keeps_the_vehicle_within_half_a_metre() {
    // m0 loses 30 % of its thrust at 32 s; the hover window (from 31 s, 20 s after the flight
    // ramp, to 60 s) holds the loss and the 28 s after it. The default profile flies on
    // (simulated) GPS fixes, with the torque observer on.
    let (r, _logs) = thrust_loss_report(&[]);
    assert!(r["halt"].is_null(), "{r}");
    let window_start = r["hover_window_start_s"].as_f64().unwrap();
    assert!(window_start < 32.0, "{r}");
    assert!(r["hover_samples"].as_u64().unwrap() >= 2_850, "{r}");
    // The true position, in 3-D, never more than 0.5 m from the set point.
    let worst = r["pos_max_err_m"].as_f64().unwrap();
    assert!(worst <= 0.5, "up to {worst} m from the set point: {r}");
    assert!(r["alt_max_err_m"].as_f64().unwrap() <= worst);
    assert!(r["alt_rms_m"].as_f64().unwrap() <= 0.2, "{r}");
    // The vehicle stays level once the torque is cancelled.
    assert!(r["pitch_rms_rad"].as_f64().unwrap() <= 0.02, "{r}");
}

#[test]
fn thrust_loss_without_the_torque_observer_moves_the_vehicle() {
    // The same loss cancelled only by the x, y integrators: the torque tilts the vehicle
    // until the position error has grown enough to integrate it away.
    let (r, _logs) = thrust_loss_report(&["--set", "control.torque_observer_s=0"]);
    assert!(r["halt"].is_null(), "{r}");
    let worst = r["pos_max_err_m"].as_f64().unwrap();
    assert!(worst > 1.0, "only {worst} m from the set point: {r}");
}

#[test]
fn thrust_loss_brings_the_2012_gains_down() {
    // The same loss with the 2012 flights' gains and filter noise: their altitude loop (8.8 rad/s
    // per m, integral capped at 2 m s) cannot make up the lost thrust, which is why the default
    // profile carries its own design.
    let gains = [
        "--set",
        "control.integrators=\"psi,phi,z,theta\"",
        "--set",
        "control.k_prop_file=\"K_prop_full_ppzt.txt\"",
        "--set",
        "control.k_int_file=\"K_int_full_ppzt.txt\"",
        "--set",
        "control.torque_observer_s=0",
    ];
    let (r, _logs) = thrust_loss_report(&[&gains[..], &EKF_2012[..]].concat());
    let worst = r["alt_max_err_m"].as_f64().unwrap();
    assert!(worst > 0.5, "altitude error only {worst} m: {r}");
}

#[test]
fn bad_injections_are_refused() {
    for bad in ["imu-stall", "wind@3", "imu-stall@-1", "imu-stall@soon"] {
        let o = uquad(&root(), &["sim", "--inject", bad]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--inject"), "{bad}: {err}");
    }
}

/// A run folder's numeric log as rows of numbers.
fn table(r: &serde_json::Value, name: &str) -> Vec<Vec<f64>> {
    let run = std::path::Path::new(r["run_dir"].as_str().unwrap());
    read_table(&run.join(name))
        .into_iter()
        .map(|row| row.iter().map(|v| v.parse().unwrap_or(f64::NAN)).collect())
        .collect()
}

/// The truth.log row at or just before `t_s`.
fn truth_at(truth: &[Vec<f64>], t_s: f64) -> &[f64] {
    let i = truth.partition_point(|row| row[0] <= t_s);
    &truth[i.saturating_sub(1)]
}

#[test]
fn a_gps_glitch_moves_the_fixes_20_m_north_for_10_s() {
    let (r, _logs) = sim_report(&["--duration", "45", "--inject", "gps-glitch@30"]);
    let (gps, truth) = (table(&r, "gps.log"), table(&r, "truth.log"));
    let (mut inside, mut outside) = (0, 0);
    for fix in gps.iter().filter(|f| f.len() == 15) {
        let t_s = fix[0];
        // Against the true position plus the receiver's own bias, when it sampled (0.1 s
        // before it reported).
        let at = truth_at(&truth, t_s - 0.1);
        let excess_m = fix[3] - (at[1] + at[13]);
        if (30.2..=40.0).contains(&t_s) {
            inside += 1;
            assert!((15.0..=25.0).contains(&excess_m), "{t_s} s: {excess_m} m");
        } else if !(29.9..=40.3).contains(&t_s) {
            outside += 1;
            assert!(excess_m.abs() < 5.0, "{t_s} s: {excess_m} m");
        }
    }
    assert!(
        inside >= 9 && outside >= 20,
        "{inside} fixes in, {outside} out"
    );
}

#[test]
fn a_gyro_bias_steps_the_x_gyro_by_0_05_rad_s() {
    let (r, _logs) = sim_report(&["--duration", "40", "--inject", "gyro-bias@30"]);
    let (k, truth) = (table(&r, "kalman_in.log"), table(&r, "truth.log"));
    // kalman_in's x gyro against the true x rate, before and after.
    let mean_excess = |from: f64, to: f64| {
        let rows: Vec<f64> = k
            .iter()
            .filter(|row| (from..to).contains(&row[0]))
            .map(|row| row[6] - truth_at(&truth, row[0])[10])
            .collect();
        rows.iter().sum::<f64>() / rows.len() as f64
    };
    let step = mean_excess(31.0, 40.0) - mean_excess(20.0, 29.9);
    assert!(
        (step - 0.05).abs() < 0.01,
        "the x gyro stepped by {step} rad/s"
    );
}

#[test]
fn a_gyro_stuck_at_rest_keeps_the_calibration_refused_and_the_replay_takes_it_again_too() {
    // Calibrating at rest before arming, the gyro sticks at 2 s: each calibration it ends is
    // refused (no rates) and taken again, and every arm is refused naming it; nothing spins.
    let (status, r, _logs) = common::sim_report(&[
        "--fast",
        "--set",
        "imu.calibrate=\"before-arm\"",
        "--script",
        "arm@7,arm@13",
        "--duration",
        "15",
        "--inject",
        "gyro-stuck@2",
    ]);
    assert!(status.success(), "{r}");
    let why: Vec<&str> = r["refusals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["why"].as_str().unwrap())
        .collect();
    assert_eq!(why.len(), 2, "{r}");
    for w in why {
        assert!(w.starts_with("estimator: IMU calibrat"), "{r}");
    }
    let run = std::path::Path::new(r["run_dir"].as_str().unwrap());
    let err = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(
        err.matches("IMU calibration not plausible (calibration: the gyro gives no rates (stuck)): calibrating again").count() >= 2,
        "{err}"
    );
    assert_eq!(report_modes(&r), ["disarmed"], "{r}");
    assert_replays_same(run, &["mode.log", "kalman_in.log"]);
}

#[test]
fn calibrated_before_arming_the_ground_timer_starts_once_the_escs_run() {
    // The barometer dies during the ESCs' ramp (armed at 7 s under a running estimate): the
    // takeoff is refused, and the motors idle on the ground for commander.disarm_ground_s from
    // the ramp's end (9.4 s), not from the first Kalman step (5.7 s, disarmed).
    let (status, r, _logs) = common::sim_report(&[
        "--fast",
        "--set",
        "imu.calibrate=\"before-arm\"",
        "--script",
        "arm@7,takeoff@10",
        "--duration",
        "25",
        "--inject",
        "baro-fail@8",
    ]);
    assert!(status.success(), "{r}");
    assert_eq!(report_modes(&r), ["disarmed", "armed", "disarmed"], "{r}");
    let why = r["refusals"][0]["why"].as_str().unwrap();
    assert!(why.starts_with("estimator: innovation test ratios"), "{r}");
    let disarmed_s = r["modes"][2]["t_s"].as_f64().unwrap();
    assert!((19.3..=19.5).contains(&disarmed_s), "{r}");
    let idle_s = r["safety"]["ground_run_max_s"].as_f64().unwrap();
    assert!((9.9..=10.1).contains(&idle_s), "{r}");
}
