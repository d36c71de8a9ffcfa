//! The pilot's radio end to end, in `sim --fast` with a simulated transmitter whose SBUS or
//! CRSF frames go through the decoders, the channel map and the commander as a board's UART
//! would: arming by the arm switch, the kill switch in the air (the motors stopped at its
//! frame, the run going on, an arm again once it is off), the RC-loss failsafe both ways a
//! receiver loses its transmitter, and replays of those runs to identical bytes.

mod common;
use common::*;
use serde_json::Value;

/// `uquad sim --fast --config config/uquad.toml ARGS`: exit status, report, run folder.
fn fast(args: &[&str]) -> (bool, Value, std::path::PathBuf, tempfile::TempDir) {
    let mut all = vec!["--fast", "--config", "config/uquad.toml"];
    all.extend_from_slice(args);
    let (status, r, logs) = sim_report(&all);
    let run = run_dir(logs.path());
    (status.success(), r, run, logs)
}

fn failsafes(r: &Value) -> Vec<(String, String, f64)> {
    let list = r["failsafes"].as_array().expect("failsafes");
    list.iter()
        .map(|f| {
            let s = |k: &str| f[k].as_str().unwrap_or("?").to_string();
            (
                s("kind"),
                s("action"),
                f["t_s"].as_f64().unwrap_or(f64::NAN),
            )
        })
        .collect()
}

/// The run's one failsafe is `rc-loss`, acted on by a return: its time, s.
fn the_one_failsafe_is_an_rc_loss_return(r: &Value, what: &str) -> f64 {
    let f = failsafes(r);
    assert_eq!(f.len(), 1, "{what}: {r}");
    assert_eq!(
        (f[0].0.as_str(), f[0].1.as_str()),
        ("rc-loss", "return"),
        "{r}"
    );
    f[0].2
}

/// The flight touched down at 0.5 m/s or less.
fn assert_soft_touchdown(r: &Value, what: &str) {
    let v = r["touchdown"]["v_m_s"].as_f64().unwrap_or(f64::NAN);
    assert!(
        v <= 0.5,
        "{what}: touchdown at {v} m/s ({})",
        r["est_error"]
    );
}

#[test]
fn the_kill_switch_stops_the_motors_at_its_frame_and_the_run_goes_on() {
    let script = "switch arm on@8,takeoff@12,switch kill on@20,switch kill off@25,\
                  switch arm off@25,switch arm on@27,disarm@29";
    let (ok, r, run, _logs) = fast(&["--rc", "sbus", "--script", script, "--duration", "35"]);
    assert!(ok, "{r}");
    assert!(
        r["halt"].is_null(),
        "the kill switch is not the watchdog's halt: {r}"
    );
    assert_eq!(
        report_modes(&r),
        [
            "disarmed", "armed", "takeoff", "hold", "disarmed", "armed", "disarmed"
        ],
        "{r}"
    );
    let flights = r["flights"].as_array().expect("flights");
    assert_eq!(flights[0]["end_why"], "kill switch", "{r}");
    let kill = &r["kill_switch"][0];
    let frame_s = kill["frame_s"].as_f64().unwrap();
    assert!((20.0..20.01).contains(&frame_s), "{kill}");
    // Stopped at the frame, not at the next control step.
    assert_eq!(kill["confirmed_s"], kill["frame_s"], "{kill}");
    assert!(kill["height_m"].as_f64().unwrap() > 0.9, "{kill}");
    let impact = kill["impact_v_m_s"].as_f64().unwrap();
    assert!(impact < -3.5, "a free fall from a metre: {kill}");
    // The receiver's counts: every frame a frame, none refused.
    let rc = &r["rc"];
    assert!(rc["frames"].as_u64().unwrap_or(0) > 4_000, "{rc}");
    assert_eq!(
        (
            rc["rejected_frames"].as_u64(),
            rc["discarded_bytes"].as_u64()
        ),
        (Some(0), Some(0))
    );
    assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);
}

#[test]
fn a_lost_radio_returns_and_lands_whether_the_receiver_flags_it_or_falls_silent() {
    // SBUS: the receiver's failsafe flag, at once; CRSF: its silence, within rc_timeout_s
    // (0.5 s) of its last frame (the receiver is heard 2.5 times a timeout: no sooner than
    // 0.3 s).
    for (protocol, earliest_s, latest_s) in [("sbus", 0.0, 0.02), ("crsf", 0.29, 0.51)] {
        let script = "switch arm on@8,takeoff@12,switch mode hold@16";
        let args = [
            "--rc",
            protocol,
            "--script",
            script,
            "--inject",
            "rc-loss@25",
            "--duration",
            "70",
        ];
        let (ok, r, run, _logs) = fast(&args);
        assert!(ok, "{protocol}: {r}");
        let after_s = the_one_failsafe_is_an_rc_loss_return(&r, protocol) - 25.0;
        assert!(
            (earliest_s..=latest_s).contains(&after_s),
            "{protocol}: the failsafe {after_s} s after the loss"
        );
        assert_eq!(
            report_modes(&r)[3..],
            ["hold", "return", "land", "disarmed"],
            "{protocol}: {r}"
        );
        assert_soft_touchdown(&r, protocol);
        assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);
    }
}

#[test]
fn an_arm_by_switch_needs_the_throttle_low_and_a_radios_moves_need_a_radio() {
    let script = "sticks 0 0 0 0@6,switch arm on@8,sticks 0 0 0 -1@9,switch arm off@9.5,\
                  switch arm on@10,switch arm off@12";
    let (ok, r, _run, _logs) = fast(&["--rc", "crsf", "--script", script, "--duration", "20"]);
    assert!(ok, "{r}");
    let refusals = r["refusals"].as_array().expect("refusals");
    assert!(
        refusals.iter().any(|x| x["command"] == "arm"
            && x["why"]
                .as_str()
                .unwrap_or("")
                .starts_with("rc: throttle not low")),
        "{r}"
    );
    assert_eq!(report_modes(&r), ["disarmed", "armed", "disarmed"], "{r}");
    let o = uquad(
        &root(),
        &[
            "sim",
            "--fast",
            "--script",
            "switch arm on@8",
            "--duration",
            "10",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("add --rc sbus or --rc crsf"), "{err}");
}

/// The pilot's box: armed by the switch, a takeoff by the throttle into `position`, four
/// 10 m sides flown by the pitch and roll sticks at half travel (1.5 m/s) with a stop at each
/// corner, then `hold` and `land` by the mode switch.
const BOX: &str = "switch arm on@8,sticks 0 0 0 0.7@12,sticks 0 0 0 0@15,\
                   sticks 0 0.5 0 0@20,sticks 0 0 0 0@26.6667,\
                   sticks 0.5 0 0 0@30,sticks 0 0 0 0@36.6667,\
                   sticks 0 -0.5 0 0@40,sticks 0 0 0 0@46.6667,\
                   sticks -0.5 0 0 0@50,sticks 0 0 0 0@56.6667,\
                   switch mode hold@60,switch mode land@64";

/// The set point's horizontal position at `t_s` (setpoint.log: time, then x, y, z).
fn set_point_at(run: &std::path::Path, t_s: f64) -> [f64; 2] {
    let text = std::fs::read_to_string(run.join("setpoint.log")).expect("setpoint.log");
    let row = text
        .lines()
        .filter_map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .filter_map(|w| w.parse().ok())
                .collect();
            (v.len() >= 3).then(|| [v[0], v[1], v[2]])
        })
        .min_by(|a, b| (a[0] - t_s).abs().total_cmp(&(b[0] - t_s).abs()))
        .expect("a set point");
    [row[1], row[2]]
}

#[test]
fn the_sticks_fly_a_ten_metre_box_in_position_then_the_switch_holds_and_lands() {
    for protocol in ["sbus", "crsf"] {
        let (ok, r, run, _logs) = fast(&["--rc", protocol, "--script", BOX, "--duration", "75"]);
        assert!(ok, "{protocol}: {r}");
        assert_eq!(
            report_modes(&r),
            [
                "disarmed", "armed", "takeoff", "position", "hold", "land", "disarmed"
            ],
            "{protocol}: {r}"
        );
        // The corners where the sticks rest: each side 10 m (1.5 m/s for 6.67 s, its ramps
        // at both ends), at right angles, and the box closed.
        let corners: Vec<[f64; 2]> = [19.9, 29.9, 39.9, 49.9, 59.9]
            .iter()
            .map(|&t| set_point_at(&run, t))
            .collect();
        for (i, w) in corners.windows(2).enumerate() {
            let side_m = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            assert!(
                (side_m - 10.0).abs() < 0.1,
                "{protocol}: side {i} is {side_m} m: {corners:?}"
            );
        }
        let (a, b) = (corners[0], corners[4]);
        assert!((a[0] - b[0]).hypot(a[1] - b[1]) < 0.1, "{corners:?}");
        let d = |i: usize| {
            [
                corners[i + 1][0] - corners[i][0],
                corners[i + 1][1] - corners[i][1],
            ]
        };
        let dot = d(0)[0] * d(1)[0] + d(0)[1] * d(1)[1];
        assert!(
            dot.abs() < 1.0,
            "{protocol}: the first corner is square: {corners:?}"
        );
        assert_soft_touchdown(&r, protocol);
        assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);
    }
}

#[test]
fn a_radio_lost_in_position_returns_and_lands_and_without_gps_altitude_lands() {
    // In position, mid-box with a fix: return, then land.
    let (ok, r, run, _logs) = fast(&[
        "--rc",
        "sbus",
        "--script",
        BOX,
        "--inject",
        "rc-loss@33",
        "--duration",
        "90",
    ]);
    assert!(ok, "{r}");
    let loss_s = the_one_failsafe_is_an_rc_loss_return(&r, "position");
    assert!((0.0..0.02).contains(&(loss_s - 33.0)), "{loss_s}");
    assert_eq!(
        report_modes(&r)[3..],
        ["position", "return", "land", "disarmed"],
        "{r}"
    );
    assert_soft_touchdown(&r, "the radio lost");
    let home_m = r["touchdown"]["from_takeoff_m"]
        .as_f64()
        .unwrap_or(f64::NAN);
    assert!(home_m < 5.0, "the return came home: {home_m} m");
    assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);

    // The fixes lost in position: `altitude` at once, its sticks flying on past the gps-loss
    // landing's grace (a pilot is on them); then the radio lost: a landing (no position to
    // return to).
    let script = "switch arm on@8,sticks 0 0 0 0.7@12,sticks 0 0 0 0@15";
    let (ok, r, run, _logs) = fast(&[
        "--rc",
        "sbus",
        "--script",
        script,
        "--inject",
        "gps-loss@25",
        "--inject",
        "rc-loss@45",
        "--duration",
        "60",
    ]);
    assert!(ok, "{r}");
    assert_eq!(
        report_modes(&r)[3..],
        ["position", "altitude", "land", "disarmed"],
        "{r}"
    );
    let modes = r["modes"].as_array().expect("modes");
    let t = |i: usize| modes[i]["t_s"].as_f64().unwrap_or(f64::NAN);
    assert!(t(5) - 45.0 < 0.02, "landed by the radio's loss: {r}");
    assert_soft_touchdown(&r, "the radio lost");
    assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);
}
