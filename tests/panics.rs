//! A panic anywhere in the flight stops the motors: a panic injected in the controller task
//! (a test-only hook, `FlyOptions::control_panic_at`) zeroes and disables every ESC at once,
//! ends the run, and its message reaches the run's error, err.log and the report.

mod common;
use common::*;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_panic_stops_the_motors_and_fails_the_run() {
    let opts = uquad::app::fly::FlyOptions {
        control_panic_at: Some(50),
        ..Default::default()
    };
    let (summary, _, bus, _logs) = fly_with(
        &FLY_TOLERANT,
        opts,
        Link::Pipe,
        Box::new(|_, f| Some(f)),
        |_| tokio::time::sleep(Duration::from_secs(20)),
    )
    .await;
    let text = summary.text();
    let error = summary.error.clone().unwrap_or_default();
    assert!(
        error.contains("the controller task panicked: injected controller panic at step 50"),
        "{text}"
    );
    // The motors were halted for the panic, not by the shutdown that followed.
    assert_eq!(summary.esc_stop_reason.as_deref(), Some("panic"), "{text}");
    assert_ends_zero_then_disable(&bus.transactions());
    // Nothing after the panic was commanded: the last flight command is step 49's.
    assert!(summary.esc_commands <= 50, "{text}");
    let err = std::fs::read_to_string(summary.run_dir.join("err.log")).unwrap();
    assert!(
        err.contains("error: the controller task panicked: injected controller panic at step 50"),
        "{err}"
    );
    let report = serde_json::to_value(summary.report()).unwrap();
    assert!(
        report["error"]
            .as_str()
            .is_some_and(|e| e.contains("injected controller panic")),
        "{report}"
    );
}
