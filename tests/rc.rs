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
        let f = failsafes(&r);
        assert_eq!(f.len(), 1, "{protocol}: {r}");
        assert_eq!(
            (f[0].0.as_str(), f[0].1.as_str()),
            ("rc-loss", "return"),
            "{r}"
        );
        let after_s = f[0].2 - 25.0;
        assert!(
            (earliest_s..=latest_s).contains(&after_s),
            "{protocol}: the failsafe {after_s} s after the loss"
        );
        assert_eq!(
            report_modes(&r)[3..],
            ["hold", "return", "land", "disarmed"],
            "{protocol}: {r}"
        );
        let v = r["touchdown"]["v_m_s"].as_f64().unwrap_or(f64::NAN);
        assert!(v <= 0.5, "{protocol}: touchdown at {v} m/s");
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
