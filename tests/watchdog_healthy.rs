//! A healthy 60-second flight (through the pty, on the mock bus, with the default watchdog):
//! no trip and no deadline miss. Its own test binary, so nothing else runs beside it.

mod common;
use common::*;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_healthy_minute_has_no_trip_and_no_deadline_miss() {
    let (summary, sent, _bus, _logs) = fly_for(
        &DEFAULT_TIMEOUTS,
        None,
        tokio::time::sleep(Duration::from_secs(63)),
    )
    .await;
    assert!(summary.error.is_none(), "{:?}", summary.error);
    assert!(summary.halt.is_none(), "{}", summary.text());
    assert_eq!(summary.deadline_misses, 0, "{}", summary.text());
    assert_eq!(summary.esc_stop_reason.as_deref(), Some("shutdown"));
    // About 60 s of flight after the 3 s start-up: 100 steps a second.
    assert!(
        summary.steps >= 5_800,
        "{} steps of {sent} frames",
        summary.steps
    );
    assert_eq!(summary.dropped_frames, 0);
    assert_eq!(summary.log_drops_total(), 0);
    let report = summary.report();
    assert_eq!(report["watchdog_trips"], 0);
    assert_eq!(report["halt"], serde_json::Value::Null);
    let p99 = report["latency_us"]["p99"].as_u64().unwrap();
    assert!(p99 < 10_000, "p99 latency {p99} us");
}
