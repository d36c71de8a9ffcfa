//! The commander end to end: `uquad sim` as the README runs it flies the whole cycle and lands
//! softly; each failsafe ends on the ground without a cut in the air; arming is refused with the
//! failing check named; disarm in the air is refused and kill halts; a console arms, takes off
//! and lands a `sim --realtime` after a refusal for an unwritable log folder.

mod common;
use common::*;
use serde_json::Value;
use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// `uquad sim --fast --config config/uquad.toml ARGS`: its exit status and report.
fn fast(args: &[&str]) -> (bool, Value, tempfile::TempDir) {
    let mut all = vec!["--fast", "--config", "config/uquad.toml"];
    all.extend_from_slice(args);
    let (status, r, logs) = sim_report(&all);
    (status.success(), r, logs)
}

/// When mode `name` was entered first, s.
fn mode_at(r: &Value, name: &str) -> f64 {
    let list = r["modes"].as_array().unwrap();
    let m = list.iter().find(|m| m["mode"] == name);
    m.unwrap_or_else(|| panic!("no {name}: {r}"))["t_s"]
        .as_f64()
        .unwrap()
}

fn failsafes(r: &Value) -> Vec<(String, String)> {
    let list = r["failsafes"].as_array().unwrap();
    list.iter()
        .map(|f| {
            let s = |k: &str| f[k].as_str().unwrap().to_string();
            (s("kind"), s("action"))
        })
        .collect()
}

fn refusal(r: &Value, command: &str) -> String {
    let list = r["refusals"].as_array().unwrap();
    let f = list.iter().find(|f| f["command"] == command);
    f.unwrap_or_else(|| panic!("no refusal of {command}: {r}"))["why"]
        .as_str()
        .unwrap()
        .to_string()
}

/// Every simulated ESC ends disabled after a zero speed and a disable (or, on the ground
/// between flights, the disables that probe whether it answers).
fn assert_escs_stopped(r: &Value) {
    for e in r["esc_end"].as_array().unwrap() {
        assert_eq!(e["enabled"], false, "{r}");
        let stopped = serde_json::json!(["speed 0", "disable"]);
        let probed = serde_json::json!(["disable", "disable"]);
        assert!(
            e["last_writes"] == stopped || e["last_writes"] == probed,
            "{r}"
        );
    }
}

/// Landed and disarmed with no halt: no cut in the air, the touchdown soft enough.
fn assert_landed(ok: bool, r: &Value, v_max_m_s: f64) {
    assert!(ok, "{r}");
    assert!(r["halt"].is_null(), "{r}");
    assert_eq!(
        report_modes(r).last().map(String::as_str),
        Some("disarmed"),
        "{r}"
    );
    assert_eq!(r["esc"]["stop_reason"], "disarmed", "{r}");
    let v = r["touchdown"]["v_m_s"].as_f64().unwrap_or(f64::NAN);
    assert!(v <= v_max_m_s, "touchdown at {v} m/s: {r}");
    assert_escs_stopped(r);
}

#[test]
fn the_main_job_flies_the_whole_cycle_and_lands_softly() {
    let (ok, r, _logs) = fast(&[]);
    let want = ["disarmed", "armed", "takeoff", "hold", "land", "disarmed"];
    assert_eq!(report_modes(&r), want, "{r}");
    assert_landed(ok, &r, 0.5);
    let climb = r["takeoff"]["target_m"].as_f64().unwrap();
    let over = r["takeoff"]["overshoot_m"].as_f64().unwrap();
    assert_eq!(climb, 1.0);
    assert!(
        over <= 0.05 * climb,
        "overshoot {over} m of a {climb} m climb"
    );
    assert!(r["failsafes"].as_array().unwrap().is_empty(), "{r}");
    // The run ended once disarmed, not at sim.duration_s.
    assert!(r["simulated_s"].as_f64().unwrap() < 55.0, "{r}");
}

/// Three flights in one run: each armed, flown and landed, each in the report with its own
/// figures, and the run replayed to identical bytes. A profile that calibrates after arming
/// flies once and says why a second arm is refused.
#[test]
fn a_run_flies_three_flights_each_reported_and_replays_them_exactly() {
    let script = "arm@7,takeoff@10,land@22,arm@40,takeoff@43,land@55,arm@72,takeoff@75,land@87";
    let (ok, r, logs) = fast(&["--script", script, "--duration", "120"]);
    let cycle = ["armed", "takeoff", "hold", "land", "disarmed"];
    let mut want = vec!["disarmed"];
    for _ in 0..3 {
        want.extend(cycle);
    }
    assert_eq!(report_modes(&r), want, "{r}");
    let flights = r["flights"].as_array().expect("flights");
    assert_eq!(flights.len(), 3, "{r}");
    for (f, armed_s) in flights.iter().zip([7.0, 40.0, 72.0]) {
        assert_eq!(f["armed_s"].as_f64(), Some(armed_s), "{f}");
        assert_eq!(f["end_mode"], "disarmed", "{f}");
        assert_eq!(f["end_why"], "touchdown", "{f}");
        let v = f["touchdown"]["v_m_s"].as_f64().unwrap_or(f64::NAN);
        assert!(v <= 0.5, "touchdown at {v} m/s: {f}");
        let over = f["takeoff"]["overshoot_m"].as_f64().unwrap_or(f64::NAN);
        assert!(over <= 0.05, "overshoot {over} m: {f}");
        assert!(f["touchdown"]["t_s"].as_f64().unwrap() > armed_s, "{f}");
    }
    assert_landed(ok, &r, 0.5);
    let run = run_dir(logs.path());
    assert_replays_same(&run, &["mode.log", "x_hat.log", "w.log", "int.log"]);

    let (_, r, _logs) = fast(&[
        "--set",
        "imu.calibrate=\"after-arm\"",
        "--script",
        "arm@2,takeoff@6,land@14,arm@30",
        "--duration",
        "40",
    ]);
    assert!(
        refusal(&r, "arm").starts_with("landed: one flight per run in this profile"),
        "{r}"
    );
    assert_eq!(r["flights"].as_array().map(Vec::len), Some(1), "{r}");
}

#[test]
fn a_lost_link_lands_without_a_cut() {
    let (ok, r, _logs) = fast(&["--inject", "link-loss@30"]);
    assert_eq!(failsafes(&r), [("link-loss".into(), "land".into())], "{r}");
    // The last heartbeat at 29 s, lost 2 s later (failsafe.link_timeout_s).
    let land = mode_at(&r, "land");
    assert!((31.0..31.1).contains(&land), "land at {land}: {r}");
    assert_landed(ok, &r, 0.5);
}

#[test]
fn a_lost_gps_holds_altitude_then_lands() {
    let (ok, r, _logs) = fast(&["--inject", "gps-loss@30"]);
    assert_eq!(failsafes(&r), [("gps-loss".into(), "land".into())], "{r}");
    // The last fix at 29 s (the receiver's 0.1 s later), lost after
    // control.gps_hold_timeout_s (3 s), then failsafe.gps_loss_land_s (10 s) of holding
    // before the landing.
    let land = mode_at(&r, "land");
    assert!((42.0..42.2).contains(&land), "land at {land}: {r}");
    // The hover window (31 s to the landing) holds the altitude.
    let alt = r["alt_max_err_m"].as_f64().unwrap();
    assert!(alt <= 0.2, "altitude error {alt} m: {r}");
    assert!(r["hover_samples"].as_u64().unwrap() >= 1000, "{r}");
    assert_landed(ok, &r, 0.5);
}

#[test]
fn a_fence_breach_lands_near_the_fence() {
    let (ok, r, _logs) = fast(&["--set", "fence.radius_m=2", "--inject", "gust@30"]);
    // The breach lands; pushed out again while landing, it is recorded again (same action).
    let f = failsafes(&r);
    assert!(!f.is_empty(), "{r}");
    assert!(
        f.iter().all(|f| *f == ("geofence".into(), "land".into())),
        "{r}"
    );
    let from = r["touchdown"]["from_takeoff_m"].as_f64().unwrap();
    assert!(
        from <= 2.0 + 2.0,
        "touchdown {from} m from the takeoff: {r}"
    );
    // A gust of a fifth of the weight while landing: down, but not as softly.
    assert_landed(ok, &r, 1.0);
}

#[test]
fn arming_is_refused_with_the_failing_check_named() {
    let (ok, r, _logs) = fast(&["--duration", "12", "--inject", "gps-loss@0"]);
    assert!(ok, "{r}");
    assert!(refusal(&r, "arm").starts_with("gps: no fix"), "{r}");
    assert_eq!(report_modes(&r), ["disarmed"], "{r}");
    assert_eq!(r["esc"]["commands"], 0, "{r}");

    let (ok, r, _logs) = fast(&["--duration", "12", "--inject", "esc-nack@0"]);
    assert!(ok, "{r}");
    assert_eq!(
        refusal(&r, "arm"),
        "esc: no acknowledgement from 0x69, 0x6b, 0x6a, 0x68",
        "{r}"
    );
    assert_eq!(report_modes(&r), ["disarmed"], "{r}");
    assert!(
        r["halt"].is_null(),
        "the probes are no watchdog matter: {r}"
    );
}

/// The IMU silent before the arm: the `arm` waits for no frame past commander.input_expiry_s
/// and is refused, never applied; the run ends in error (the flight could not start).
#[test]
fn an_arm_while_the_imu_is_silent_expires_and_the_run_fails() {
    let (ok, r, logs) = fast(&[
        "--duration",
        "8",
        "--script",
        "arm@1",
        "--inject",
        "imu-stall@0.8",
    ]);
    assert!(!ok, "{r}");
    assert!(
        refusal(&r, "arm").starts_with("not applied within commander.input_expiry_s = 1 s"),
        "{r}"
    );
    let error = r["error"].as_str().unwrap_or_default();
    assert_eq!(
        error, "the flight could not start: the IMU was silent from 0.79 s to the end (8.00 s)",
        "{r}"
    );
    assert_eq!(report_modes(&r), ["disarmed"], "{r}");
    let mode_log = std::fs::read_to_string(run_dir(logs.path()).join("mode.log")).unwrap();
    assert!(
        mode_log.contains("8000000 expired 7000000 in gcs arm\n"),
        "{mode_log}"
    );
}

/// A garbled IMU: the odd frame that decodes after seconds of garbage does not vouch for the
/// IMU: an `arm` on it is refused as stale; the run ends in error.
#[test]
fn an_arm_on_a_stale_imu_verdict_is_refused() {
    let (ok, r, _logs) = fast(&[
        "--duration",
        "30",
        "--script",
        "arm@3",
        "--inject",
        "imu-garbage@1",
    ]);
    assert!(!ok, "{r}");
    let why = refusal(&r, "arm");
    assert!(why.starts_with("imu: no frame for "), "{r}");
    assert!(why.ends_with("its verdict is stale"), "{r}");
    assert_eq!(report_modes(&r), ["disarmed"], "{r}");
    assert!(
        r["error"]
            .as_str()
            .unwrap_or_default()
            .starts_with("the flight could not start"),
        "{r}"
    );
}

#[test]
fn an_implausible_calibration_refuses_the_arming_after_all() {
    // A gyro offset of 0.5 rad/s (a broken gyro, or a vehicle turning while calibrated).
    // Calibrated after the arm (the original's order); at rest, before it, the calibration
    // is taken again instead and every arm refused (tests/sim_faults.rs).
    let bias = "sim.gyro_bias_rad_s=[0.5, 0.0, 0.0]";
    let after = "imu.calibrate=\"after-arm\"";
    let (ok, r, _logs) = fast(&[
        "--duration",
        "15",
        "--set",
        bias,
        "--set",
        after,
        "--script",
        "arm@2",
    ]);
    assert!(!ok, "a failed start-up fails the run: {r}");
    assert!(
        refusal(&r, "arm").starts_with("calibration: gyro offset 0.49"),
        "{r}"
    );
    assert_eq!(report_modes(&r), ["disarmed", "armed", "disarmed"], "{r}");
    assert!(r["error"].as_str().unwrap().contains("calibration"), "{r}");
    assert_escs_stopped(&r);
}

#[test]
fn disarm_in_the_air_is_refused_and_kill_halts() {
    let script = "arm@7,takeoff@10,disarm@20,kill@25";
    let (ok, r, _logs) = fast(&["--script", script]);
    assert!(!ok, "a halt fails the run: {r}");
    assert!(
        refusal(&r, "disarm").starts_with("in the air (hold)"),
        "{r}"
    );
    assert_eq!(r["halt"]["reason"], "kill", "{r}");
    assert_eq!(r["halt"]["confirmed"], true, "{r}");
    assert_eq!(
        report_modes(&r).last().map(String::as_str),
        Some("kill"),
        "{r}"
    );
    assert_escs_stopped(&r);
    // The replay has no watchdog: it takes the halt from mode.log, to the same bytes.
    let run = Path::new(r["run_dir"].as_str().unwrap()).to_path_buf();
    assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log"]);
}

/// Waits until a console line contains `text`.
fn wait_for(lines: &Mutex<Vec<String>>, text: &str, limit: Duration) {
    let t0 = Instant::now();
    while !lines.lock().unwrap().iter().any(|l| l.contains(text)) {
        assert!(t0.elapsed() < limit, "no {text:?} within {limit:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_console_arms_takes_off_and_lands_after_a_refusal() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("console.sock");
    let socket = format!("console.socket=\"{}\"", sock.display());
    let mut cmd = realtime_sim(
        &[
            "--set",
            "commander.start=disarmed",
            "--script",
            "none",
            "--duration",
            "60",
            "--set",
            &socket,
        ],
        dir.path(),
    );
    cmd.env("RUST_LOG", "info");
    let mut child = Uquad::spawn(&mut cmd);
    let run = run_dir(dir.path());
    let t0 = Instant::now();
    while !sock.exists() {
        assert!(t0.elapsed() < Duration::from_secs(10), "no console socket");
        std::thread::sleep(Duration::from_millis(20));
    }
    let console = UnixStream::connect(&sock).unwrap();
    let mut send = console.try_clone().unwrap();
    let lines = reader(console);
    let long = Duration::from_secs(20);
    // Settled before this console may have attached: err.log keeps what it missed.
    let t0 = Instant::now();
    while !std::fs::read_to_string(run.join("err.log"))
        .unwrap_or_default()
        .contains("calibrating at rest, motors off")
    {
        assert!(t0.elapsed() < long, "never settled:\n{}", child.stderr());
        std::thread::sleep(Duration::from_millis(50));
    }
    // The log folder taken away (a card pulled): a file where the folder was.
    let moved = dir.path().join("moved");
    std::fs::rename(&run, &moved).unwrap();
    std::fs::write(&run, b"not a folder").unwrap();
    // The folder is probed once a second: two probes.
    std::thread::sleep(Duration::from_millis(2500));
    send.write_all(b"arm\n").unwrap();
    wait_for(&lines, "arm refused: log: cannot write in", long);
    // Given back, the same command arms; then takeoff, land.
    std::fs::remove_file(&run).unwrap();
    std::fs::rename(&moved, &run).unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    // Arming waits for the estimate calibrated at rest (the pre-arm check `estimator`): asked
    // again, as an operator would, until it is taken.
    let t0 = Instant::now();
    while !lines
        .lock()
        .unwrap()
        .iter()
        .any(|l| l.contains("mode armed: command arm"))
    {
        assert!(t0.elapsed() < long, "never armed:\n{}", child.stderr());
        send.write_all(b"arm\n").unwrap();
        std::thread::sleep(Duration::from_millis(500));
    }
    wait_for(&lines, "ESC ramp done; idling", long);
    send.write_all(b"takeoff 1.5\n").unwrap();
    wait_for(&lines, "mode hold: takeoff height reached", long);
    send.write_all(b"disarm\n").unwrap();
    wait_for(&lines, "disarm refused: in the air", long);
    send.write_all(b"land\n").unwrap();
    // Landed, the run goes on (another flight may follow) until the operator quits.
    wait_for(&lines, "mode disarmed: touchdown", Duration::from_secs(40));
    send.write_all(b"quit\n").unwrap();
    let status = child.child.wait().unwrap();
    assert!(status.success(), "{status}\n{}", child.stderr());
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let want = ["disarmed", "armed", "takeoff", "hold", "land", "disarmed"];
    assert_eq!(report_modes(&r), want, "{r}");
    assert!(
        refusal(&r, "arm").starts_with("log: cannot write in"),
        "{r}"
    );
    assert_eq!(r["takeoff"]["target_m"], 1.5, "{r}");
    assert_landed(true, &r, 0.5);
    assert_eq!(r["deadline_misses"], 0, "{r}");
    // The console's commands are in the run's mode.log, as a replay reads them.
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(mode_log.contains(" in console takeoff 1.5\n"), "{mode_log}");
    assert!(
        mode_log.contains(" in console arm | log: cannot write in"),
        "{mode_log}"
    );
}

/// `uquad sim --realtime` with ARGS to its end: its report, run folder and stderr.
fn realtime(args: &[&str]) -> (Value, std::path::PathBuf, String, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let mut child = Uquad::spawn(&mut realtime_sim(args, dir.path()));
    let status = child.child.wait().unwrap();
    let stderr = child.stderr();
    let text = std::fs::read_to_string(dir.path().join("report.json"))
        .unwrap_or_else(|_| panic!("{status}: no report\n{stderr}"));
    let r: Value = serde_json::from_str(&text).unwrap();
    assert!(status.success(), "{status}: {r}\n{stderr}");
    let run = std::path::PathBuf::from(r["run_dir"].as_str().unwrap());
    (r, run, stderr, dir)
}

#[test]
fn a_lost_link_lands_on_the_wall_clock_too() {
    let (r, _run, stderr, _dir) = realtime(&[
        "--set",
        "commander.start=disarmed",
        "--script",
        "arm@7,takeoff@10,land@60",
        "--inject",
        "link-loss@17",
        "--duration",
        "45",
    ]);
    assert_eq!(
        failsafes(&r),
        [("link-loss".into(), "land".into())],
        "{r}\n{stderr}"
    );
    assert_landed(true, &r, 0.5);
    // Ended once disarmed, long before --duration.
    assert!(r["simulated_s"].as_f64().unwrap() < 35.0, "{r}");
}

/// Column `col` of `log`'s rows whose time (column 0) lies in `from_s..to_s`, averaged.
fn mean_between(log: &Path, col: usize, from_s: f64, to_s: f64) -> f64 {
    let rows: Vec<f64> = numbers(log)
        .into_iter()
        .filter(|r| (from_s..to_s).contains(&r[0]))
        .map(|r| r[col])
        .collect();
    assert!(
        !rows.is_empty(),
        "{}: no rows in {from_s}..{to_s}",
        log.display()
    );
    rows.iter().sum::<f64>() / rows.len() as f64
}

#[test]
fn the_flight_faults_strike_on_the_wall_clock_too() {
    // thrust-loss: m0 speeds up to make up its lost thrust; log-stall: the x_hat logger
    // blocks for 500 ms (records queue, then drop and are counted), no deadline is missed.
    let (r, run, stderr, _dir) = realtime(&[
        "--inject",
        "thrust-loss@12",
        "--inject",
        "log-stall@12",
        "--duration",
        "18",
    ]);
    let w = run.join("w.log");
    let before = mean_between(&w, 1, 10.5, 12.0);
    let after = mean_between(&w, 1, 14.0, 18.0);
    assert!(after > before * 1.1, "m0 {before:.1} -> {after:.1} rad/s");
    assert!(stderr.contains("log writes stalled"), "{stderr}");
    assert_eq!(r["deadline_misses"], 0, "{r}");
    // The true state went to truth.log frame by frame, on the logs' clock: a row for every
    // Kalman step at least, and the vehicle truly at its height in the hover.
    let truth = run.join("truth.log");
    let kalman = numbers(&run.join("kalman_in.log"));
    assert!(numbers(&truth).len() >= kalman.len(), "{stderr}");
    let height_m = mean_between(&truth, 3, 14.0, 18.0);
    assert!(
        (0.5..1.5).contains(&height_m),
        "true height {height_m:.2} m\n{stderr}"
    );
    // gust: pushed north (seen on the fixes); gps-loss: the failsafe, 3 s after the last fix.
    let (r, run, stderr, _dir) = realtime(&[
        "--inject",
        "gust@12",
        "--inject",
        "gps-loss@16",
        "--duration",
        "21",
    ]);
    // This profile reads no drag: once the fixes are lost its position's uncertainty grows
    // by metres a second, and the fence, judged on where the vehicle may be, lands it too.
    let fs = failsafes(&r);
    assert_eq!(fs[0], ("gps-loss".into(), "land".into()), "{r}\n{stderr}");
    assert!(
        fs[1..].iter().all(|(k, a)| k == "geofence" && a == "land"),
        "{r}\n{stderr}"
    );
    let x_hat = numbers(&run.join("x_hat.log"));
    let north = x_hat.iter().map(|x| x[0]).fold(f64::MIN, f64::max);
    assert!(north > 0.5, "pushed {north:.2} m north");
}

/// A ground station repeating `hold` ten times a second: the report lists the first 100
/// re-entries of the mode and counts them all, and the landing after them is listed (the
/// report kept the first 1000 events, and a later landing was missing).
#[test]
fn repeated_commands_are_summarised_and_the_landing_after_them_listed() {
    let holds: Vec<String> = (0..150)
        // From 16 s: the takeoff reaches its height (hold) at 15.6 s.
        .map(|i| format!("hold@{:.1}", 16.0 + 0.1 * f64::from(i)))
        .collect();
    let script = format!("arm@7,takeoff@10,{},land@45", holds.join(","));
    let (ok, r, _logs) = fast(&["--script", &script]);
    assert!(ok, "{r}");
    assert_eq!(r["mode_reentries_total"], 150, "{r}");
    assert_eq!(r["mode_reentry_last"]["t_s"], 30.9, "{r}");
    let modes = report_modes(&r);
    assert_eq!(
        modes.iter().filter(|m| *m == "hold").count(),
        101,
        "{modes:?}"
    );
    assert_eq!(modes[modes.len() - 2..], ["land", "disarmed"], "{modes:?}");
}
