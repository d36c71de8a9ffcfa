//! Signals and crashes of a running flight (`sim --realtime`, which runs `fly`'s own tasks):
//! SIGHUP, SIGTERM and a double SIGINT each stop the motors first (zero, then disable: the
//! simulated ESCs' last writes), and the report and err.log are still written in full; a
//! `kill -9` after the calibration leaves err.log on disk with the start-up's lines.

mod common;
use common::*;
use std::path::Path;
use std::time::{Duration, Instant};

/// One flight at a time: each takes a core for its physics and control threads.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Starts a 60-second realtime sim in `dir` and waits until its IMU calibration is complete.
fn flying(dir: &Path) -> Uquad {
    let mut cmd = realtime_sim(&["--duration", "60"], dir);
    let run = Uquad::spawn(cmd.env("RUST_LOG", "info"));
    let start = Instant::now();
    while !run.stderr().contains("IMU calibration completed") {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no calibration:\n{}",
            run.stderr()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    run
}

fn send(run: &Uquad, signal: i32) {
    // SAFETY: kill with a child's pid and a signal number.
    let rc = unsafe { libc::kill(run.child.id() as i32, signal) };
    assert_eq!(rc, 0);
}

/// Waits (at most 30 s) for the run to end; its exit status.
fn ended(run: &mut Uquad) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(s) = run.child.try_wait().unwrap() {
            return s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the run did not end"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn stopped_in_order_by(signals: &[(i32, &str)]) {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let mut run = flying(dir.path());
    for &(s, _) in signals {
        send(&run, s);
        std::thread::sleep(Duration::from_millis(30));
    }
    let status = ended(&mut run);
    let stderr = run.stderr();
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("report.json"))
            .unwrap_or_else(|e| panic!("no report ({e}): {stderr}")),
    )
    .unwrap();
    assert!(status.success(), "{status}: {report}\n{stderr}");
    assert_eq!(report["esc"]["stop_reason"], "shutdown", "{report}");
    for e in report["esc_end"].as_array().unwrap() {
        assert_eq!(e["enabled"], false, "{e}");
        assert_eq!(
            e["last_writes"],
            serde_json::json!(["speed 0", "disable"]),
            "{e}"
        );
    }
    let err = std::fs::read_to_string(run_dir(dir.path()).join("err.log")).unwrap();
    let name = signals[0].1;
    assert!(
        err.contains(&format!("signal {name}: stopping the motors")),
        "{err}"
    );
    let last = err.lines().last().unwrap_or_default();
    assert!(last.starts_with("run ended:"), "err.log incomplete:\n{err}");
}

#[test]
fn sighup_stops_the_motors_then_writes_the_report_and_logs() {
    stopped_in_order_by(&[(libc::SIGHUP, "SIGHUP")]);
}

#[test]
fn sigterm_stops_the_motors_then_writes_the_report_and_logs() {
    stopped_in_order_by(&[(libc::SIGTERM, "SIGTERM")]);
}

#[test]
fn a_double_sigint_still_stops_the_motors_first_and_writes_everything() {
    stopped_in_order_by(&[(libc::SIGINT, "SIGINT"), (libc::SIGINT, "SIGINT")]);
}

#[test]
fn sigtstp_does_not_suspend_a_flight() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let mut run = flying(dir.path());
    send(&run, libc::SIGTSTP);
    // A suspended process would stop answering: the run goes on and ends on SIGTERM.
    std::thread::sleep(Duration::from_millis(300));
    assert!(run.child.try_wait().unwrap().is_none(), "{}", run.stderr());
    send(&run, libc::SIGTERM);
    assert!(ended(&mut run).success(), "{}", run.stderr());
    assert!(run.stderr().contains("SIGTSTP ignored"), "{}", run.stderr());
}

#[test]
fn kill_9_after_the_calibration_leaves_the_start_up_in_err_log() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let mut run = flying(dir.path());
    // err.log reaches the kernel with each batch: a few ms after the line was logged.
    std::thread::sleep(Duration::from_millis(200));
    send(&run, libc::SIGKILL);
    ended(&mut run);
    let err = std::fs::read_to_string(run_dir(dir.path()).join("err.log")).unwrap();
    for line in [
        "uquad ",
        "IMU sampling period stable; ESC start-up ramp",
        "ESC ramp done; IMU calibration",
        "IMU calibration completed",
    ] {
        assert!(err.contains(line), "{line:?} missing from err.log:\n{err}");
    }
}
