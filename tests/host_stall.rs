//! A stall of the whole host is not a fault of the IMU or of the control path: `uquad sim
//! --realtime` stopped by SIGSTOP for 200 ms (every thread at once, as a virtual machine's
//! pause or a kernel's hiccup stops them), once with the motors idling and once hovering,
//! flies on: no halt and no stale-command stop, the motors running under the commander
//! (which may land on a failsafe it names: frames were lost in the pause); the report counts
//! the stalls and the longest gap between the watchdog's checks. The stops are seconds
//! apart: the time excused is budgeted (250 ms of credit, refilled at 250 ms a second).
//!
//! The stall is made here, not waited for: the test does not depend on this machine's timing.
//! The watchdog's rules over such a stall are unit-tested in `core::watchdog`.

mod common;
use common::*;
use std::time::{Duration, Instant};

/// How long the process is held stopped, ms: twice the tests' IMU timeout and deadline, above
/// their ESC command timeout (150 ms), within the excused budget (a pause of up to about
/// 330 ms).
const STOP_MS: u64 = 200;

/// Polls `run`'s stderr until it holds `line` (at most 60 s).
fn wait_for(run: &Uquad, line: &str) {
    let t0 = Instant::now();
    while !run.stderr().contains(line) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "never saw {line:?}:\n{}",
            run.stderr()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// One realtime run at a time: two would share this machine's two CPUs.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A realtime run of `duration_s` flying from the start (one at a time), its folder and
/// process.
fn start(duration_s: &str) -> (std::sync::MutexGuard<'static, ()>, tempfile::TempDir, Uquad) {
    let one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let run =
        Uquad::spawn(realtime_sim(&["--duration", duration_s], dir.path()).env("RUST_LOG", "info"));
    (one, dir, run)
}

/// The run's report.
fn report(dir: &tempfile::TempDir) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap()).unwrap()
}

/// Stops the whole process for [`STOP_MS`], then lets it go on.
fn stall(run: &mut Uquad) {
    stall_for(run, STOP_MS);
}

/// Stops the whole process for `stop_ms`, then lets it go on.
fn stall_for(run: &mut Uquad, stop_ms: u64) {
    assert!(
        run.child.try_wait().unwrap().is_none(),
        "the run ended before the stall:\n{}",
        run.stderr()
    );
    let pid = run.child.id() as i32;
    // SAFETY: kill with a child's pid and a signal number.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGSTOP) }, 0);
    std::thread::sleep(Duration::from_millis(stop_ms));
    // SAFETY: as above.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGCONT) }, 0);
}

#[test]
fn a_stopped_host_is_counted_and_neither_a_silent_imu_nor_a_missed_deadline() {
    let (_one, dir, mut run) = start("16");
    // The motors idling after their ramp: a silent IMU would halt them.
    wait_for(&run, "ESC start-up ramp done");
    stall(&mut run);
    // Hovering: every frame is owed a command within the deadline, and the ESC writer
    // stops a command older than esc.command_timeout_ms.
    wait_for(&run, "mode hold");
    std::thread::sleep(Duration::from_millis(500));
    stall(&mut run);
    let status = run.child.wait().unwrap();
    let err = run.stderr();
    assert!(status.success(), "{status}: {err}");
    let report = report(&dir);
    assert!(report["halt"].is_null(), "{err}");
    // The motors ran on: the ESCs were stopped by the run's end or the commander's disarm
    // after a landing, never as a stale command.
    let stop = report["esc"]["stop_reason"].as_str().unwrap();
    assert!(stop == "shutdown" || stop == "disarmed", "{stop}: {err}");
    assert_eq!(report["deadline_misses"], 0, "{err}");
    assert!(report["host_stalls"].as_u64().unwrap() >= 2, "{err}");
    let gap_ms = report["watchdog_gap_max_ms"].as_f64().unwrap();
    assert!(gap_ms >= (STOP_MS - 20) as f64, "{gap_ms} ms: {err}");
    assert!(err.contains("host stalls over 5 ms: "), "{err}");
    // The flight went on after both stalls, in the commander's hands: still holding, or
    // landing on a failsafe it named (frames were lost in the pause, and the estimate may
    // have to say it is unsure), never killed.
    let modes = report["modes"].as_array().unwrap();
    let last = modes.last().unwrap()["mode"].as_str().unwrap();
    let failsafes = report["failsafes"].as_array().unwrap();
    assert!(
        last == "hold" || (["land", "disarmed"].contains(&last) && !failsafes.is_empty()),
        "{last}: {err}"
    );
}

#[test]
fn a_pause_beyond_the_budget_stops_the_motors() {
    // 700 ms stopped while hovering: more than the budget excuses (about 330 ms at once), so
    // the IMU's silence or the command's age is judged on the wall clock and the motors stop
    // (whichever of the watchdog and the ESC writer wakes first names it).
    let (_one, dir, mut run) = start("14");
    wait_for(&run, "mode hold");
    stall_for(&mut run, 700);
    run.child.wait().unwrap();
    let err = run.stderr();
    let report = report(&dir);
    let stop = report["esc"]["stop_reason"].as_str().unwrap();
    assert!(
        ["imu-timeout", "deadline", "stale motor command"].contains(&stop),
        "{stop}: {err}"
    );
    let gap_ms = report["watchdog_gap_max_ms"].as_f64().unwrap();
    assert!(gap_ms >= 680.0, "{gap_ms} ms: {err}");
}
