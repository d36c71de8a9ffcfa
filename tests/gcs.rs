//! The ground-station link end to end, with a real client: pymavlink (installed by the test
//! command, `tests/run.sh`, into a virtual environment; `UQUAD_PYTHON` names its python)
//! against `uquad sim --mode paced` (and `--realtime` where the real threads are the subject)
//! over UDP loopback. The client's scenarios are in
//! `tests/gcs_client.py`.

mod common;
use common::*;
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};

/// The python that has pymavlink.
fn python() -> String {
    std::env::var("UQUAD_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Starts the client for `scenario`; returns it and the `--set` that points the vehicle's
/// link at it: the UDP port it listens on, or the pty standing in for its radio.
fn start_client(scenario: &[&str]) -> (Child, String) {
    let script = root().join("tests/gcs_client.py");
    let mut child = Command::new(python())
        .arg(&script)
        .args(scenario)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    let mut first = String::new();
    let stdout = child.stdout.as_mut().unwrap();
    BufReader::new(stdout).read_line(&mut first).unwrap();
    let first = first.trim();
    let link = if let Some(pty) = first.strip_prefix("pty ") {
        Some(format!("gcs.serial=\"{pty}\""))
    } else {
        first
            .strip_prefix("port ")
            .and_then(|p| p.parse::<u16>().ok())
            .map(|port| format!("gcs.udp_remote=\"127.0.0.1:{port}\""))
    };
    let Some(link) = link else {
        let out = child.wait_with_output().unwrap();
        panic!(
            "the client did not start (pymavlink missing? run tests/run.sh, or set \
             UQUAD_PYTHON to a python that has it): {first}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    (child, link)
}

/// What a scenario left: the client's JSON line, the run's report, its folder, and the
/// temporary folder holding them.
struct Flown {
    measured: Value,
    report: Value,
    run: std::path::PathBuf,
    _dir: tempfile::TempDir,
}

/// Runs `scenario` against `sim --mode paced` at twice the wall clock given `args`; the run
/// succeeds. The paced simulator serves the same link as `fly` and judges its watchdog on the
/// simulated clock, so a stall of this shared machine slows a scenario instead of halting
/// it: these tests are about the ground station, not the host's scheduling.
fn fly_paced(scenario: &[&str], args: &[&str]) -> Flown {
    let paced = |args: &[&str], dir: &std::path::Path| paced_sim("2", args, dir);
    fly_against(paced, scenario, args, true)
}

/// Runs `scenario` against `sim --realtime` given `args`, the run's exit status a success
/// exactly when `succeeds`: for what only the real threads do (an input answered while the
/// IMU is silent; telemetry on the clock the run logs by), in a short run.
fn fly_realtime_ending(scenario: &[&str], args: &[&str], succeeds: bool) -> Flown {
    fly_against(realtime_sim, scenario, args, succeeds)
}

/// The lines of `text` that contain `part`.
fn lines_with(text: &str, part: &str) -> usize {
    text.lines().filter(|l| l.contains(part)).count()
}

/// Runs `scenario` against the simulation `sim` builds given `args`.
fn fly_against(
    sim: impl Fn(&[&str], &std::path::Path) -> Command,
    scenario: &[&str],
    args: &[&str],
    succeeds: bool,
) -> Flown {
    let dir = tempfile::tempdir().unwrap();
    let (mut client, remote) = start_client(scenario);
    let kept = format!(
        "gcs.params_file=\"{}\"",
        dir.path().join("params.toml").display()
    );
    let base = [
        "--set",
        "commander.start=disarmed",
        "--script",
        "none",
        "--set",
        &remote,
        "--set",
        &kept,
    ];
    let duration: &[&str] = if args.contains(&"--duration") {
        &[]
    } else {
        &["--duration", "150"]
    };
    let mut cmd = sim(&[&base[..], duration, args].concat(), dir.path());
    cmd.args(["--set", "gcs.enabled=sim-realtime"]);
    let mut sim = Uquad::spawn(&mut cmd);
    let mut stdin = client.stdin.take().unwrap();
    writeln!(stdin, "started").unwrap();
    let run = run_dir(dir.path());
    writeln!(stdin, "run {}", run.display()).unwrap();
    let out = client.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "client: {stdout}\n{}\n--- uquad ---\n{}",
        String::from_utf8_lossy(&out.stderr),
        sim.stderr()
    );
    let status = end_run(&mut sim);
    let report_path = dir.path().join("report.json");
    let text = std::fs::read_to_string(&report_path)
        .unwrap_or_else(|_| panic!("{status}: no report\n{}", sim.stderr()));
    let report: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        status.success(),
        succeeds,
        "{status}: {report}\n{}",
        sim.stderr()
    );
    let line = stdout.lines().last().unwrap_or("{}");
    let measured: Value = serde_json::from_str(line).unwrap();
    eprintln!("client measured: {measured}\ngcs report: {}", report["gcs"]);
    Flown {
        measured,
        report,
        run,
        _dir: dir,
    }
}

fn u(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn a_ground_station_sets_a_parameter_arms_takes_off_and_lands() {
    let count = uquad::gcs::params::TABLE.len().to_string();
    let flown = fly_paced(&["fly", &count], &[]);
    let (measured, r, run) = (&flown.measured, &flown.report, &flown.run);
    assert!(
        measured["heartbeat_s"].as_f64().unwrap() <= 2.0,
        "{measured}"
    );
    assert!(
        measured["alt_err_max_m"].as_f64().unwrap() <= 0.2,
        "{measured}"
    );
    // Before arming a ground station sees a global position, the home and the pre-arm bit
    // (their times measured, not judged).
    for k in ["position_s", "home_s", "prearm_s"] {
        assert!(
            measured["before_arming"][k].as_f64().is_some(),
            "{measured}"
        );
    }
    // MAVLink FTP answered (a NAK: nothing served yet), its time measured, not judged.
    assert!(measured["ftp_answer_ms"].as_f64().is_some(), "{measured}");
    let modes = report_modes(r);
    assert_eq!(
        modes,
        // Hold asked for three ways (QGroundControl's SET_MODE, MAVSDK's DO_SET_MODE, a
        // COMMAND_INT), then return and land by DO_SET_MODE in PX4's modes.
        [
            "disarmed", "armed", "takeoff", "hold", "hold", "hold", "hold", "return", "land",
            "disarmed"
        ],
        "{r}"
    );
    // The names pymavlink (and MAVProxy) give the modes it saw: hold, return, land.
    assert_eq!(
        measured["mode_names"],
        serde_json::json!(["LOITER", "RTL", "LAND"]),
        "{measured}"
    );
    assert_eq!(r["takeoff"]["target_m"], 1.5, "{r}");
    assert_eq!(r["deadline_misses"], 0, "{r}");
    let g = &r["gcs"];
    // arm (refused), arm, takeoff, REQUEST_MESSAGE, SET_MESSAGE_INTERVAL twice, hold three
    // ways, position (refused), AVAILABLE_MODES, return, land. The sets kept: the climb rate,
    // and an integer set bytewise (4), then C cast (3).
    assert!(u(&g["commands"]) >= 10 && u(&g["param_sets"]) == 3, "{g}");
    assert!(u(&g["commands_refused"]) >= 3, "{g}");
    // System 42 announced itself as a quadrotor: its ARM and parameter set were denied (the
    // kept set below is the ground station's 0.4, not its 0.3).
    assert_eq!(u(&g["senders_denied"]), 2, "{g}");
    // The set is kept for the next start and noted in the run, which keeps its values.
    let kept = std::fs::read_to_string(run.parent().unwrap().join("params.toml")).unwrap();
    assert!(kept.contains("climb_m_s = 0.4"), "{kept}");
    assert!(kept.contains("max_missed_acks = 3"), "{kept}");
    let run_config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(run_config.contains("climb_m_s = 0.5"), "{run_config}");
    assert!(run_config.contains("# parameter CMD_CLIMB_M_S (commander.climb_m_s) set to 0.4"));
    let err_log = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(err_log.contains("parameter CMD_CLIMB_M_S"), "{err_log}");
    // The ground station's commands are the run's operator inputs, as a replay reads them.
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(mode_log.contains(" in gcs takeoff 1.5\n"), "{mode_log}");
    assert!(
        mode_log.contains(" in gcs arm | log: cannot write in"),
        "{mode_log}"
    );
    // The set parameter did not change the flight: its replay is the same, byte for byte.
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}

/// With the IMU silent, a ground station's ARM is answered at commander.input_expiry_s and
/// never applied later; the run ends in error: the flight could not start.
#[test]
fn an_arm_the_flight_cannot_take_is_refused_in_time_and_the_run_fails() {
    let args = ["--inject", "imu-stall@1", "--duration", "12"];
    let flown = fly_realtime_ending(&["stalled"], &args, false);
    let (measured, r, run) = (&flown.measured, &flown.report, &flown.run);
    // Answered at the expiry (1 s), well before the link's own 5 s timeout.
    assert!(
        measured["arm_answered_s"].as_f64().unwrap() < 4.0,
        "{measured}"
    );
    let error = r["error"].as_str().unwrap_or_default();
    assert!(
        error.starts_with("the flight could not start: the IMU was silent from"),
        "{r}"
    );
    assert_eq!(report_modes(r), ["disarmed"], "{r}");
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(mode_log.contains(" expired "), "{mode_log}");
    assert!(mode_log.contains(" in gcs arm\n"), "{mode_log}");
    assert!(
        mode_log.contains(" refused arm | not applied within commander.input_expiry_s = 1 s"),
        "{mode_log}"
    );
}

/// MAVLink 2 signing: with `gcs.signing_key_file`, a ground station signing with the key
/// commands the vehicle; unsigned frames and frames signed with another key are dropped and
/// counted (any sender was obeyed, and signatures were not checked).
#[test]
fn with_a_signing_key_only_signed_frames_are_heard() {
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("signing.key");
    std::fs::write(&key_file, "uquad test passphrase\n").unwrap();
    let set = format!("gcs.signing_key_file=\"{}\"", key_file.display());
    let flown = fly_paced(&["signed"], &["--duration", "20", "--set", &set]);
    let r = &flown.report;
    let g = &r["gcs"];
    assert!(u(&g["unsigned"]) >= 2, "{g}");
    assert!(u(&g["bad_signature"]) >= 2, "{g}");
    assert_eq!(u(&g["bad_crc"]), 0, "{g}");
    let modes = report_modes(r);
    assert_eq!(modes[..2], ["disarmed", "armed"], "{r}");
    assert_eq!(modes.last().map(String::as_str), Some("disarmed"), "{r}");
}

/// `uquad params` prints the mapping a ground station sees, with the kept values applied.
#[test]
fn uquad_params_lists_every_mapped_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("params.toml"), "[fence]\nradius_m = 30.0\n").unwrap();
    let log_dir = dir.path().to_str().unwrap();
    let o = uquad(&root(), &["params", "--log-dir", log_dir]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let rows: Vec<Vec<&str>> = text
        .lines()
        .skip(1)
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(rows.len(), uquad::gcs::params::TABLE.len(), "{text}");
    assert!(
        rows.contains(&vec![
            "FEN_RADIUS_M",
            "fence.radius_m",
            "30",
            "yes",
            "start"
        ]),
        "{text}"
    );
    assert!(
        rows.contains(&vec!["SIM_GUST_N", "sim.gust_n", "3", "no", "start"]),
        "{text}"
    );
    assert!(
        rows.contains(&vec![
            "CMD_LAND_M_S",
            "commander.land_m_s",
            "0.5",
            "no",
            "flight"
        ]),
        "{text}"
    );
}

#[test]
fn a_silent_ground_station_lands_the_vehicle_and_noise_is_counted() {
    let flown = fly_paced(&["link-loss"], &[]);
    let (measured, r) = (&flown.measured, &flown.report);
    let failsafes = r["failsafes"].as_array().unwrap();
    assert!(
        failsafes
            .iter()
            .any(|f| f["kind"] == "link-loss" && f["action"] == "land"),
        "{r}"
    );
    assert!(r["touchdown"].is_object(), "{r}");
    assert!(r["halt"].is_null(), "{r}");
    assert_eq!(r["deadline_misses"], 0, "{r}");
    let g = &r["gcs"];
    assert!(u(&g["bad_crc"]) >= 50, "{g}");
    assert!(u(&g["truncated"]) >= 50, "{g}");
    assert!(u(&g["unknown"]) >= 50, "{g}");
    // Most of the 50 × 64 random bytes.
    assert!(u(&g["garbage_bytes"]) > 1000, "{g}");
    // The flood was 450 frames a second against a budget of 200.
    assert!(u(&g["flood_drops"]) > 0, "{g} {measured}");
}

/// The parameters a ground station kept apply at the next start, under --set.
#[test]
fn kept_parameters_apply_at_the_next_start_and_are_named_when_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let kept = dir.path().join("params.toml");
    std::fs::write(&kept, "[commander]\nclimb_m_s = 0.4\n").unwrap();
    let cfg = root().join("config/uquad.toml");
    let path = Some(dir.path());
    let (p, applied) = uquad::config::load_kept(&cfg, &[], path).unwrap();
    assert_eq!(p.config.commander.climb_m_s, 0.4);
    assert_eq!(applied, Some((kept.clone(), 1)));
    let sets = [uquad::config::parse_set("commander.climb_m_s=0.3").unwrap()];
    let (p, _) = uquad::config::load_kept(&cfg, &sets, path).unwrap();
    assert_eq!(p.config.commander.climb_m_s, 0.3, "--set wins");
    std::fs::write(&kept, "[commander]\nclimb_m_s = 99.0\n").unwrap();
    let e = uquad::config::load_kept(&cfg, &[], path)
        .unwrap_err()
        .to_string();
    assert!(e.contains(&format!("(from {})", kept.display())), "{e}");
}

/// The link over a serial radio: a pty stands for it; the test speaks MAVLink on the other
/// end with the `mavlink` crate's own reader and writer.
#[test]
fn the_link_runs_over_a_serial_radio() {
    use mavlink::dialects::common::{COMMAND_LONG_DATA, MavCmd, MavMessage, MavResult};
    use serialport::SerialPort;
    use std::time::{Duration, Instant};
    let (mut master, slave) = serialport::TTYPort::pair().expect("a pty pair");
    let path = slave.name().expect("the pty's name");
    master.set_timeout(Duration::from_millis(200)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let serial = format!("gcs.serial=\"{path}\"");
    let args = ["--script", "none", "--duration", "30", "--set", &serial];
    let mut cmd = paced_sim("1", &args, dir.path());
    cmd.args(["--set", "gcs.enabled=sim-realtime"]);
    let sim = Uquad::spawn(&mut cmd);
    let mut reader = mavlink::MavlinkReader::new(master.try_clone().unwrap());
    let mut next = |what: &str, want: &dyn Fn(&MavMessage) -> bool| {
        let t0 = Instant::now();
        loop {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "no {what}\n{}",
                sim.stderr()
            );
            if let Ok((_, m)) = reader.read_any_message::<MavMessage>()
                && want(&m)
            {
                return m;
            }
        }
    };
    next("HEARTBEAT", &|m| matches!(m, MavMessage::HEARTBEAT(_)));
    let ask = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
        param1: 148.0,
        target_system: 1,
        target_component: 1,
        ..COMMAND_LONG_DATA::DEFAULT
    });
    let header = mavlink::MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    mavlink::write_v2_msg(&mut master, header, &ask).unwrap();
    next("AUTOPILOT_VERSION", &|m| {
        matches!(m, MavMessage::AUTOPILOT_VERSION(_))
    });
    let ack = next("COMMAND_ACK", &|m| matches!(m, MavMessage::COMMAND_ACK(_)));
    let MavMessage::COMMAND_ACK(ack) = ack else {
        unreachable!()
    };
    assert_eq!(ack.result, MavResult::MAV_RESULT_ACCEPTED);
}

/// A mission uploaded by a ground station (MISSION_COUNT, MISSION_REQUEST_INT,
/// MISSION_ITEM_INT, MISSION_ACK), downloaded back, started by asking for the Mission mode
/// (DO_SET_MODE AUTO MISSION, as MAVSDK sends it) and followed
/// with MISSION_CURRENT and MISSION_ITEM_REACHED; the upload is a file in the run folder,
/// and the run replays to the same bytes.
#[test]
fn a_ground_station_uploads_a_mission_and_the_vehicle_flies_it() {
    let flown = fly_paced(&["mission"], &[]);
    let (measured, r, run) = (&flown.measured, &flown.report, &flown.run);
    assert_eq!(
        measured["reached"],
        serde_json::json!([0, 1, 2, 3, 4]),
        "{measured}"
    );
    // Every item is current in its turn; the mission ends complete (MISSION_STATE 5).
    let current: Vec<u64> = measured["current"]
        .as_array()
        .unwrap()
        .iter()
        .map(u)
        .collect();
    for seq in 1..=4 {
        assert!(current.contains(&seq), "{measured}");
    }
    assert!(current.windows(2).all(|w| w[0] <= w[1]), "{measured}");
    assert!(
        measured["states"].as_array().unwrap().contains(&5.into()),
        "{measured}"
    );
    let modes = report_modes(r);
    assert_eq!(
        modes,
        [
            "disarmed", "armed", "takeoff", "mission", "land", "disarmed"
        ],
        "{r}"
    );
    assert_eq!(r["deadline_misses"], 0, "{r}");
    // The refused upload's file stays in the run folder; the flown one is recorded by name.
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(
        mode_log.contains(" mission mission-2.toml gains "),
        "{mode_log}"
    );
    assert!(run.join("mission-1.toml").is_file());
    let err_log = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(
        err_log.contains("mission mission-2.toml loaded: 5 items"),
        "{err_log}"
    );
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}

#[test]
fn calibrated_before_arming_a_ground_station_sees_the_estimate_and_the_check_that_waits() {
    // Realtime: time_boot_ms is the wall clock's, kalman_in.log the run's; paced they differ.
    let args = ["--set", "imu.calibrate=\"before-arm\""];
    let flown = fly_realtime_ending(&["before-arm"], &args, true);
    let (measured, r, run) = (&flown.measured, &flown.report, &flown.run);
    let refusal = measured["refusal"].as_str().unwrap();
    assert!(
        refusal.starts_with("arm refused: estimator: IMU calibrating at rest"),
        "{measured}"
    );
    // The first Kalman step is the calibration's end (the run's clock, as time_boot_ms).
    let kalman = read_table(&run.join("kalman_in.log"));
    let calibrated_s: f64 = kalman[0][0].parse().unwrap();
    for what in ["attitude", "position"] {
        let at_s = u(&measured[format!("{what}_boot_ms")]) as f64 / 1e3;
        assert!(
            at_s - calibrated_s <= 1.0,
            "{what} at {at_s} s, calibrated at {calibrated_s} s: {measured}"
        );
        assert_eq!(measured[format!("{what}_disarmed")], true, "{measured}");
    }
    assert_eq!(
        report_modes(r),
        ["disarmed", "armed", "takeoff", "hold", "land", "disarmed"],
        "{r}"
    );
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(mode_log.contains(" escs running\n"), "{mode_log}");
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}

/// Three flights in one `sim --mode paced --script none` run, flown by a ground station
/// (arm, takeoff, land, three times): each in the report, and the run replayed to identical
/// bytes. Paced at twice the wall clock: the simulator's pacing, not the host, sets its time.
#[test]
fn a_ground_station_flies_three_flights_in_one_paced_run_replayed_exactly() {
    let flown = fly_paced(&["flights", "3"], &[]);
    let (r, run) = (&flown.report, &flown.run);
    let mut want = vec!["disarmed"];
    for _ in 0..3 {
        want.extend(["armed", "takeoff", "hold", "land", "disarmed"]);
    }
    assert_eq!(report_modes(r), want, "{r}");
    let flights = r["flights"].as_array().expect("flights");
    assert_eq!(flights.len(), 3, "{r}");
    for f in flights {
        assert_eq!(f["end_why"], "touchdown", "{f}");
        let v = f["touchdown"]["v_m_s"].as_f64().unwrap_or(f64::NAN);
        assert!(v <= 0.5, "touchdown at {v} m/s: {f}");
    }
    assert!(r["halt"].is_null(), "{r}");
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log", "int.log"]);
}

/// A parameter that takes effect in flight, set by a ground station in the air: the landing
/// that follows descends at the new speed (the set point's descent in setpoint.log), the
/// change is in mode.log, and the run replays to identical bytes.
#[test]
fn a_landing_speed_set_in_flight_changes_the_landing_and_replays_exactly() {
    let flown = fly_paced(&["land-param"], &[]);
    let (r, run) = (&flown.report, &flown.run);
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    let set_at = mode_log
        .lines()
        .find_map(|l| l.strip_suffix(" param commander.land_m_s 0.3"))
        .unwrap_or_else(|| panic!("no parameter line: {mode_log}"));
    let land_at = mode_log
        .lines()
        .find_map(|l| l.strip_suffix(" mode land command land"))
        .unwrap_or_else(|| panic!("no landing: {mode_log}"));
    let (set_s, land_s) = (secs(set_at), secs(land_at));
    let (set_line, land_line) = (
        mode_log.find(" param commander.land_m_s"),
        mode_log.find(" mode land command land"),
    );
    assert!(
        set_s <= land_s && set_line < land_line,
        "set at {set_s} s, landing at {land_s} s"
    );
    // The set point's fastest descent over any 0.5 s of the landing: the new 0.3 m/s, not
    // the profile's 0.5.
    let sp = read_table(&run.join("setpoint.log"));
    let z: Vec<(f64, f64)> = sp
        .iter()
        .filter_map(|row| Some((row[0].parse().ok()?, row[3].parse().ok()?)))
        .filter(|(t, _)| *t >= land_s)
        .collect();
    let fastest = z
        .windows(51)
        .map(|w| (w[0].1 - w[50].1) / (w[50].0 - w[0].0))
        .fold(0.0, f64::max);
    assert!(
        (0.28..=0.31).contains(&fastest),
        "the landing descended at up to {fastest} m/s"
    );
    assert_eq!(
        report_modes(r).last().map(String::as_str),
        Some("disarmed"),
        "{r}"
    );
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log", "setpoint.log"]);
}

/// µs as written in mode.log, in s.
fn secs(us: &str) -> f64 {
    us.parse::<f64>().unwrap_or(f64::NAN) / 1e6
}

/// A flight's log downloaded from `sim --mode paced` (LOG_REQUEST_LIST, LOG_REQUEST_DATA):
/// over UDP whole, read by pyulog, with telemetry flowing during it; over a pty standing in
/// for a 57 600 baud radio, a part of it, never faster than the line (the link paces its
/// output to `gcs.baud`), telemetry going on. The rates are measured, not judged: how close
/// to the line's rate a download comes depends on the host (the book's table has them).
#[test]
fn a_flights_log_downloads_over_udp_and_over_a_57600_baud_radio() {
    let flown = fly_paced(&["download", "0"], &[]);
    let m = &flown.measured;
    assert_eq!(m["bytes"], m["size"], "{m}");
    assert!(u(&m["bytes"]) > 10_000, "{m}");
    let topics: Vec<&str> = m["topics"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    for t in [
        "vehicle_attitude",
        "vehicle_local_position",
        "actuator_outputs",
    ] {
        assert!(topics.contains(&t), "{t} missing: {m}");
    }
    assert!(m["attitude_hz"].as_f64().unwrap() >= 1.0, "{m}");
    assert_eq!(
        m["log_id"], m["num_logs"],
        "the newest log is this run's: {m}"
    );

    let radio = ["--set", "gcs.baud=57600"];
    let flown = fly_paced(&["download-pty", "60000"], &radio);
    let m = &flown.measured;
    assert_eq!(m["bytes"], 60_000, "{m}");
    let line_b_s = 57_600.0 / 10.0;
    let rate = m["rate_b_s"].as_f64().unwrap();
    assert!(rate <= line_b_s, "{rate} B/s on a {line_b_s} B/s line: {m}");
    assert!(m["attitude_hz"].as_f64().unwrap() > 0.0, "{m}");
}

/// A companion computer's position target in hold (SET_POSITION_TARGET_LOCAL_NED streamed at
/// 10 Hz for 2 s): the hold point moves 3 m north, the vehicle reaches it and holds it once
/// the stream stops; the stream is one move in mode.log, and the run replays exactly.
#[test]
fn a_position_target_moves_the_hold_point_3_m_and_it_is_reached() {
    let flown = fly_paced(&["guided"], &[]);
    let (m, run) = (&flown.measured, &flown.run);
    // Reached (the client waits for it at most 30 s): how soon, in wall seconds, is measured
    // and not judged. Then held: the estimate within 1 m of the point for 3 s.
    assert!(m["reached_s"].as_f64().is_some(), "{m}");
    assert!(m["held_err_max_m"].as_f64().unwrap() <= 1.0, "{m}");
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    let moves = lines_with(&mode_log, " in gcs move ");
    assert_eq!(moves, 1, "the stream of one point is one move: {mode_log}");
    assert_eq!(flown.report["gcs"]["targets_taken"], 1, "{}", flown.report);
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}

/// A ground station's preflight calibration (gyro): disarmed, the IMU is calibrated at rest
/// again and the next arm waits for it; in the air it is denied, named; the run replays
/// exactly.
#[test]
fn a_preflight_calibration_calibrates_again_on_the_ground_and_is_denied_in_the_air() {
    let flown = fly_paced(&["calibrate"], &[]);
    let run = &flown.run;
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    let asked = lines_with(&mode_log, " in gcs calibrate");
    assert_eq!(asked, 2, "{mode_log}");
    assert!(
        mode_log.contains(" refused calibrate | hold: the IMU calibrates at rest, disarmed"),
        "{mode_log}"
    );
    let err = std::fs::read_to_string(run.join("err.log")).unwrap();
    let calibrations = err.matches("IMU calibration completed").count();
    assert_eq!(calibrations, 2, "{err}");
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}

/// RC_CHANNELS tells the pilot's radio as its receiver decodes it (a simulated SBUS
/// transmitter: sticks centred, throttle low, switches off), five times a second.
#[test]
fn a_ground_station_sees_the_radios_channels() {
    let flown = fly_paced(&["rc-channels"], &["--rc", "sbus", "--duration", "30"]);
    let m = &flown.measured;
    assert_eq!(m["chancount"], 16, "{m}");
    let chans: Vec<u64> = m["chans"]
        .as_array()
        .expect("chans")
        .iter()
        .map(u)
        .collect();
    // AETR: roll, pitch centred; throttle low; yaw centred; arm, kill off; the mode switch
    // in the middle of its first of three bands; 17 and 18 unused.
    assert_eq!(chans[..7], [1500, 1500, 988, 1500, 988, 988, 1158], "{m}");
    assert_eq!(chans[16..], [65535, 65535], "{m}");
    assert_eq!(m["rssi"], 255, "SBUS measures no link quality: {m}");
    assert!(u(&m["per_2s"]) >= 5, "{m}");
}

/// A joystick on the ground station (MANUAL_CONTROL) flies the radio's stick path: Position
/// chosen on the ground, the throttle raised takes off into it, the pitch stick flies
/// forward and centred holds; Hold ignores the sticks; the run replays exactly.
#[test]
fn a_ground_station_joystick_takes_off_and_flies_in_position_and_hold_ignores_it() {
    let flown = fly_paced(&["joystick"], &[]);
    let (m, r) = (&flown.measured, &flown.report);
    let moved = m["moved_m"].as_f64().unwrap_or(f64::NAN);
    // 3 s of the client's clock at full pitch (3 m/s after its ramp; the paced simulation
    // runs faster than the client's clock, as the machine allows).
    assert!(moved > 3.0, "{m}");
    let held = m["held_moved_m"].as_f64().unwrap_or(f64::NAN);
    // The stick would fly 18 m in those 6 s; a hold moves only as its estimate does, by a
    // tenth of each fix's innovation (the receiver's bias states, `ekf.r_gps`): 0.57 m seen
    // once after the 18 m flight.
    assert!(held < 1.0, "hold ignores the sticks: {m}");
    let modes = report_modes(r);
    assert_eq!(
        modes[..5],
        ["disarmed", "armed", "takeoff", "position", "hold"],
        "{r}"
    );
    let mode_log = std::fs::read_to_string(flown.run.join("mode.log")).unwrap();
    assert!(lines_with(&mode_log, " sticks ") > 10, "{mode_log}");
    assert_replays_same(&flown.run, &["mode.log", "w.log"]);
}

/// A motor test of each motor from a ground station, as QGroundControl sends it: on the
/// simulated ESC bus each motor in turn is driven alone (its start-up ramp, then its test
/// throttle for its time); out of bounds or armed, it is refused with the reason; a throttle
/// of 0 stops a test; the run replays exactly.
#[test]
fn a_ground_station_tests_each_motor_alone_disarmed_and_is_refused_armed() {
    use uquad::core::motor::{ESC_ENABLE_WAIT_US, MotorMap, esc_startup_ramp, esc_startup_ramp_us};
    let flown = fly_paced(&["motor-test"], &[]);
    let (r, run) = (&flown.report, &flown.run);
    let escs = r["esc_end"].as_array().expect("esc_end");
    let map = MotorMap::UQUAD;
    let value = uquad::core::esc::MotorTest::new(0, 10.0, 1.0).value;
    // From the ramp's first write to the test's last, 2 ms before its end.
    let ramp_s = (esc_startup_ramp_us() - ESC_ENABLE_WAIT_US) as f64 / 1e6;
    let full_s = ramp_s + 1.0 - 0.002;
    let mut last_start_s = 0.0;
    for (m, esc) in escs.iter().enumerate() {
        assert_eq!(esc["address"], format!("0x{:02x}", map.addresses[m]), "{r}");
        let runs = esc["runs_alone"]
            .as_array()
            .expect("a run alone of each motor");
        let run = &runs[0];
        let trimmed = (i16::from(value) + map.trims[m]) as u64;
        assert_eq!(u(&run["value"]), trimmed, "{run}");
        let seconds = run["seconds"].as_f64().unwrap();
        assert!(
            (seconds - full_s).abs() < 0.005,
            "{run}: {full_s} s expected"
        );
        // The ramp's writes, then the test's every esc.resend_ms (2 ms).
        let ramp_writes = esc_startup_ramp().count() as u64 - 1;
        assert!(u(&run["writes"]) >= ramp_writes + 495, "{run}");
        let start_s = run["start_s"].as_f64().unwrap();
        assert!(start_s > last_start_s, "motors tested in turn: {r}");
        last_start_s = start_s;
        // Motor 1's second test (5 s) was stopped by a throttle of 0 long before its end.
        let stopped = if m == 0 { 1 } else { 0 };
        assert!(runs.len() <= 1 + stopped, "{esc}");
        for later in &runs[1..] {
            assert!(later["seconds"].as_f64().unwrap() < ramp_s + 4.0, "{esc}");
        }
    }
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    for m in 1..=4 {
        // Asked again while the one before ran: each asking but one was refused.
        let asked = lines_with(&mode_log, &format!(" in gcs motor {m} 10 1 |"));
        let refused = lines_with(&mode_log, &format!(" refused motor {m} 10 1 |"));
        assert_eq!(asked - refused, 1, "motor {m}: {mode_log}");
    }
    // The stop came after the long test was taken, and was taken.
    let long = mode_log
        .rfind(" in gcs motor 1 10 5 | ok")
        .expect("the long test");
    let stop = mode_log.find(" in gcs motor 1 0 0 | ok").expect("the stop");
    assert!(stop > long, "{mode_log}");
    assert!(!mode_log.contains(" refused motor 1 0 0"), "{mode_log}");
    assert!(
        mode_log.contains(" refused motor 2 10 1 | armed: a motor test runs only disarmed"),
        "{mode_log}"
    );
    assert!(
        mode_log.contains(" refused motor 1 50 1 | motor 1 at 50 %"),
        "{mode_log}"
    );
    assert_replays_same(run, &["mode.log", "w.log", "x_hat.log"]);
}
