//! A healthy 60-second flight with the default watchdog has no trip and no deadline miss.
//!
//! Flown in the simulator on its simulated clock (`--fast`): the watchdog policy sees every
//! frame, command and estimate of a minute of flight in lock-step, so the result is the
//! policy's, not this shared machine's scheduling (the wall-clock trips are tested in
//! tests/watchdog.rs, and the latency is measured by `uquad sim --realtime --report`).

mod common;
use common::*;

#[test]
fn a_healthy_minute_has_no_trip_and_no_deadline_miss() {
    let logs = tempfile::tempdir().unwrap();
    let report = logs.path().join("report.json");
    let o = uquad(
        &root(),
        &[
            "sim",
            "--fast",
            "--duration",
            "69",
            "--config",
            "config/uquad.toml",
            "--script",
            HOVER_SCRIPT,
            "--report",
            report.to_str().unwrap(),
            "--log-dir",
            logs.path().to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["watchdog_trips"], 0, "{r}");
    assert_eq!(r["halt"], serde_json::Value::Null);
    assert_eq!(r["deadline_misses"], 0);
    // About 9 s of start-up, then a minute of flight at 100 steps a second.
    assert!(r["steps"].as_u64().unwrap() >= 5_900, "{r}");
    assert_eq!(r["esc"]["stop_reason"], "shutdown");
    let err = std::fs::read_to_string(
        std::path::Path::new(r["run_dir"].as_str().unwrap()).join("err.log"),
    )
    .unwrap();
    assert!(!err.contains("watchdog: halt"), "{err}");
}
