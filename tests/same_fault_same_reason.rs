//! One fault, one reason: every I2C write refused from the ESCs' start-up ramp on ends `fly`
//! (pty + mock bus), `sim --fast` and `sim --realtime` the same way — the watchdog's
//! `esc-ack` halt, with the same err.log line and the same report fields — because all three
//! drive the one flight sequence, ESC write loop and watchdog dispatch.

mod common;
use common::*;
use std::path::Path;
use std::time::Duration;

/// The err.log line of the halt, cut before its times (they differ run to run).
fn halt_line(run_dir: &Path) -> String {
    let err = std::fs::read_to_string(run_dir.join("err.log")).unwrap();
    let line = err
        .lines()
        .find(|l| l.starts_with("watchdog: halt"))
        .unwrap_or_else(|| panic!("no halt in err.log:\n{err}"));
    line.split("; event at")
        .next()
        .unwrap_or_default()
        .to_string()
}

/// The report's halt reason and ESC stop reason, and err.log's halt line.
fn sim_reason(mode: &str, inject: &str) -> (String, String, String) {
    let mut args = vec![
        mode,
        "--config",
        "config/uquad.toml",
        "--duration",
        "6",
        "--inject",
        inject,
        // Arming at start, so the ramp's timing is the same in every mode.
        "--set",
        "commander.start=flying",
    ];
    if mode == "--realtime" {
        args.extend_from_slice(&REALTIME_TOLERANT);
    }
    let (status, r, _logs) = sim_report(&args);
    assert!(!status.success(), "a halt fails the run: {r}");
    let run_dir = Path::new(r["run_dir"].as_str().unwrap()).to_path_buf();
    (
        r["halt"]["reason"].as_str().unwrap_or_default().to_string(),
        r["esc"]["stop_reason"]
            .as_str()
            .unwrap_or_default()
            .to_string(),
        halt_line(&run_dir),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_writes_during_the_esc_ramp_give_the_same_reason_in_every_mode() {
    let want = (
        "esc-ack".to_string(),
        "esc-ack".to_string(),
        "watchdog: halt, reason esc-ack".to_string(),
    );
    // The ESC ramp runs from about 0.5 s (settled) to 2.9 s.
    assert_eq!(sim_reason("--fast", "esc-nack@1.5"), want, "sim --fast");
    assert_eq!(
        sim_reason("--realtime", "esc-nack@1.5"),
        want,
        "sim --realtime"
    );

    // fly with the 2012 profile's short test start-up: the ramp runs from 0.05 s to 2.4 s.
    let during = |bus: uquad::hw::esc_bus::MockBus| -> std::pin::Pin<
        Box<dyn std::future::Future<Output = ()> + Send>,
    > {
        Box::pin(async move {
            tokio::time::sleep(Duration::from_millis(1_000)).await;
            bus.set_failing(true);
            tokio::time::sleep(Duration::from_secs(3)).await;
        })
    };
    let (summary, _, _, _logs) = fly_with(
        &FLY_TOLERANT,
        Default::default(),
        Link::Pty,
        Box::new(|_, f| Some(f)),
        during,
    )
    .await;
    let r = serde_json::to_value(summary.report()).unwrap();
    let fly = (
        r["halt"]["reason"].as_str().unwrap_or_default().to_string(),
        r["esc"]["stop_reason"]
            .as_str()
            .unwrap_or_default()
            .to_string(),
        halt_line(&summary.run_dir),
    );
    assert_eq!(fly, want, "fly: {}", summary.text());
}
