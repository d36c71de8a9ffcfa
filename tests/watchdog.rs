//! The watchdog halts the motors — zero, then disable, on the mock bus — for each trip cause,
//! with the reason in err.log and the report, on the wall clock.
//!
//! The latency limits themselves (the cause's limit plus one ESC period) are checked where
//! time is simulated and so exact: the policy's unit tests in `core::watchdog` (when each
//! cause decides) and `tests/sim_faults.rs` (decision to disabled ESCs: imu-timeout within
//! 14 ms, esc-ack within 12 ms). Here, on a shared machine whose threads stall for
//! milliseconds at times, the latency is bounded by the limit plus [`STALL_MS`]: enough to
//! catch a halt path that waits (a missed wake-up, a blocked writer), not a stall.

mod common;
use common::*;
use std::time::Duration;

/// Frames before the flight has surely started: 5 settling, about 240 during the ESC ramp,
/// 64 calibrating, then some flight.
const FLYING_AT_FRAME: usize = 400;

/// One flight at a time: these tests measure milliseconds on a shared 2-core machine. The
/// causes other than a silent IMU keep the common settings' 100 ms IMU timeout, so that
/// scheduling jitter cannot pre-empt the cause under test; the silent-IMU test uses 12 ms.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// What a stall of this shared machine can add to a halt's wall-clock latency, ms.
const STALL_MS: f64 = 50.0;

/// Runs until the watchdog ends the run (at most `max`), then checks the halt: the reason, the
/// latency bound, zero then disable as the last bus transactions, err.log and the report.
async fn expect_halt(
    extra: &[&str],
    opts: uquad::app::fly::FlyOptions,
    plan: FramePlan,
    during: impl FnOnce(
        uquad::hw::esc_bus::MockBus,
    ) -> std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>,
    reason: &str,
    max_latency_ms: f64,
) -> uquad::app::report::FlySummary {
    let _one = ONE_AT_A_TIME.lock().await;
    let (summary, _, bus, _logs) = fly_with(extra, opts, Link::Pipe, plan, during).await;
    let halt = summary
        .halt
        .unwrap_or_else(|| panic!("no halt: {}", summary.text()));
    assert_eq!(halt.trip.reason.name(), reason, "{}", summary.text());
    let latency = halt.latency_ms();
    let bound_ms = max_latency_ms + STALL_MS;
    // A refused stop is retried (watchdog.halt_retry_ms) before it settles: then only the
    // decision is bound by the cause's limit.
    let settled_ms = if halt.confirmed() {
        latency
    } else {
        halt.decision_ms()
    };
    assert!(
        (0.0..=bound_ms).contains(&settled_ms),
        "halt {settled_ms} ms after the event (limit {max_latency_ms} ms + {STALL_MS} ms of stalls)"
    );
    // Zero to every ESC, then disable every ESC, and nothing after.
    assert_ends_zero_then_disable(&bus.transactions());
    assert_eq!(summary.esc_stop_reason.as_deref(), Some(reason));
    // err.log and the report say why.
    let err = std::fs::read_to_string(summary.run_dir.join("err.log")).unwrap();
    assert!(
        err.contains(&format!("watchdog: halt, reason {reason}")),
        "{err}"
    );
    let stop = if halt.confirmed() {
        "stop confirmed by every ESC"
    } else {
        "stop NOT confirmed by 0x"
    };
    assert!(err.contains(stop), "{err}");
    let report_path = summary.run_dir.join("report.json");
    summary.write_report(&report_path).unwrap();
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).unwrap()).unwrap();
    assert_eq!(report["halt"]["reason"], reason);
    assert_eq!(report["watchdog_trips"], 1);
    assert_eq!(report["halt"]["latency_ms"].as_f64(), Some(latency));
    assert!(std::path::Path::new(report["run_dir"].as_str().unwrap()).is_absolute());
    summary
}

/// For the tests of the causes other than the deadline: a deadline above this shared machine's
/// stalls (about 10 ms at times in a debug build), so that none pre-empts the cause under test.
/// The deadline's own test keeps its 10 ms.
const DEADLINE_ABOVE_STALLS: [&str; 1] = ["watchdog.deadline_ms=100"];

/// The IMU timeout at its 12 ms default, with the deadline above the stalls.
const IMU_TIMEOUT_12_MS: [&str; 2] = ["watchdog.imu_timeout_ms=12", "watchdog.deadline_ms=100"];

fn no_fault() -> FramePlan {
    Box::new(|_, f| Some(f))
}

fn idle(
    max: Duration,
) -> impl FnOnce(
    uquad::hw::esc_bus::MockBus,
) -> std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>> {
    move |_| Box::pin(tokio::time::sleep(max))
}

/// The mock bus refuses every write from 4.5 s (in flight) on, for `lasting` or to the end.
fn refusing_writes(
    lasting: Option<Duration>,
) -> impl FnOnce(
    uquad::hw::esc_bus::MockBus,
) -> std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>> {
    move |bus| {
        Box::pin(async move {
            tokio::time::sleep(Duration::from_millis(4_500)).await;
            bus.set_failing(true);
            if let Some(d) = lasting {
                tokio::time::sleep(d).await;
                bus.set_failing(false);
            }
            tokio::time::sleep(Duration::from_secs(3)).await;
        })
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_imu_trips_imu_timeout() {
    // The IMU falls silent mid-flight: 12 ms timeout + 2 ms.
    let plan: FramePlan = Box::new(|k, f| (k < FLYING_AT_FRAME).then_some(f));
    expect_halt(
        &IMU_TIMEOUT_12_MS,
        Default::default(),
        plan,
        idle(Duration::from_secs(8)),
        "imu-timeout",
        14.0,
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn missed_acks_trip_esc_ack() {
    // Every I2C write fails from 4.5 s on: 3 failed cycles (6 ms) decide; 12 ms is the bound.
    let s = expect_halt(
        &DEADLINE_ABOVE_STALLS,
        Default::default(),
        no_fault(),
        refusing_writes(None),
        "esc-ack",
        12.0,
    )
    .await;
    // The disable was attempted although the bus kept failing, and retried for
    // watchdog.halt_retry_ms (500 ms): unconfirmed by every ESC.
    assert!(s.esc_failed_writes >= 8);
    let halt = s.halt.unwrap();
    assert!(!halt.confirmed(), "{}", s.text());
    assert_eq!(
        halt.unconfirmed_addresses().collect::<Vec<_>>(),
        uquad::core::motor::MotorMap::UQUAD.addresses.to_vec()
    );
    let retried_ms = halt.latency_ms() - halt.decision_ms();
    assert!(
        (500.0..=500.0 + STALL_MS).contains(&retried_ms),
        "retried for {retried_ms} ms"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_stop_is_retried_until_every_esc_acknowledges_it() {
    // Every I2C write fails from 4.5 s for 300 ms: the halt (esc-ack) is decided within the
    // refusals, its zero and disable retried until the bus answers again, then confirmed.
    let s = expect_halt(
        &DEADLINE_ABOVE_STALLS,
        Default::default(),
        no_fault(),
        refusing_writes(Some(Duration::from_millis(300))),
        "esc-ack",
        // To the last acknowledgement: the 300 ms of refusals.
        300.0,
    )
    .await;
    let halt = s.halt.unwrap();
    assert!(halt.confirmed(), "{}", s.text());
    assert!(
        halt.latency_ms() >= 250.0,
        "confirmed {} ms after the event",
        halt.latency_ms()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_control_trips_deadline() {
    // From control step 50 on each step takes 15 ms: the 10 ms deadline + 2 ms.
    let opts = uquad::app::fly::FlyOptions {
        control_delay: Some((50, Duration::from_millis(15))),
        ..Default::default()
    };
    let s = expect_halt(
        &[],
        opts,
        no_fault(),
        idle(Duration::from_secs(8)),
        "deadline",
        12.0,
    )
    .await;
    assert_eq!(s.deadline_misses, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hot_imu_trips_sanity_temp() {
    // 60 °C from mid-flight: the 21st insane step trips; the halt follows within 2 ms.
    let plan: FramePlan = Box::new(|k, mut f| {
        if k >= FLYING_AT_FRAME {
            f.temp_dc = 600;
        }
        Some(f)
    });
    expect_halt(
        &DEADLINE_ABOVE_STALLS,
        Default::default(),
        plan,
        idle(Duration::from_secs(8)),
        "sanity-temp",
        2.0,
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rolling_over_trips_sanity_tilt() {
    // A steady roll rate of about 3 rad/s from mid-flight: past 1 rad, 21 insane steps trip.
    let plan: FramePlan = Box::new(|k, mut f| {
        if k >= FLYING_AT_FRAME {
            f.gyro[0] = f.gyro[0].saturating_add(2400);
        }
        Some(f)
    });
    expect_halt(
        &DEADLINE_ABOVE_STALLS,
        Default::default(),
        plan,
        idle(Duration::from_secs(9)),
        "sanity-tilt",
        2.0,
    )
    .await;
}
