//! `fly` end to end without hardware: real frames through a pseudo-terminal into the IMU reader
//! (tokio-serial), a mock I2C bus recording every ESC transaction, then a replay of the run.

mod common;
use common::*;
use std::time::Duration;
use uquad::core::motor::{
    EscAction, MotorMap, REG_DISABLE, REG_ENABLE, REG_SPEED, esc_startup_ramp, i2c_from_rad_s,
};
use uquad::hw::esc_bus::Transaction;

/// One flight at a time: a flight shares this 2-core machine with nothing else.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fly_through_a_pty_with_a_mock_bus_then_replay() {
    let _one = ONE_AT_A_TIME.lock().await;
    // Settle 0.05 s + ESC ramp 2.37 s + calibration 0.64 s + flight ramp 1 s + 1 s of hover.
    let (summary, sent, bus, _logs) =
        fly_for(&[], None, tokio::time::sleep(Duration::from_millis(5_500))).await;
    assert!(summary.error.is_none(), "{:?}", summary.error);
    assert!(
        summary.frames > 400 && summary.frames <= sent,
        "{} of {sent}: {}",
        summary.frames,
        summary.text()
    );
    assert!(
        summary.steps > 150,
        "steps {}: {}",
        summary.steps,
        summary.text()
    );
    assert_eq!(summary.rejected_frames, 0);
    assert_eq!(summary.log_drops_total(), 0);

    let tx = bus.transactions();
    assert!(tx.iter().all(|t| t.acked));
    let map = MotorMap::UQUAD;
    let addrs = map.addresses;
    // 1. Booted disabled: only the pre-arm probes (a disable to every ESC, each 0.5 s), then
    //    the writes enable every ESC.
    let probes = tx.iter().take_while(|t| t.reg == REG_DISABLE).count();
    assert!(probes >= 4 && probes % 4 == 0, "{probes} probe writes");
    let tx = &tx[probes..];
    let first: Vec<(u8, u8, u8)> = tx[..4].iter().map(|t| (t.addr, t.reg, t.value)).collect();
    assert_eq!(first, addrs.map(|a| (a, REG_ENABLE, 0)).to_vec());
    // 2. The start-up saw-tooth, every value to every ESC, untrimmed.
    let ramp: Vec<u8> = esc_startup_ramp()
        .filter_map(|(_, a)| match a {
            EscAction::SpeedAll(v) => Some(v),
            EscAction::EnableAll => None,
        })
        .collect();
    let mut at = 4;
    for v in &ramp {
        for a in addrs {
            let t: &Transaction = &tx[at];
            assert_eq!(
                (t.addr, t.reg, t.value),
                (a, REG_SPEED, *v),
                "ramp write {at}"
            );
            at += 1;
        }
    }
    // 3. Idle with trims while calibrating, then the flight commands with trims: every row of
    //    the run's w.log appears, in order, as four trimmed speed writes.
    let run_dir = summary.run_dir.clone();
    let w = numbers(&run_dir.join("w.log"));
    assert_eq!(w.len() as u64, summary.steps);
    let speed_writes: Vec<[u8; 4]> = tx[at..]
        .chunks(4)
        .take_while(|c| c.len() == 4 && c.iter().all(|t| t.reg == REG_SPEED))
        .map(|c| {
            for (t, a) in c.iter().zip(addrs) {
                assert_eq!(t.addr, a);
            }
            [c[0].value, c[1].value, c[2].value, c[3].value]
        })
        .collect();
    let idle = map.speed_writes(&[50; 4]).map(|(_, _, v)| v);
    assert_eq!(speed_writes[0], idle, "idle 50 + trims after the ramp");
    // The writer keeps only the newest command, so a command that a newer one replaced before
    // the writer woke (frames arriving in a burst after a stall of this machine) is never
    // written. What is checked is what holds whatever the timing: every flight command written
    // (re-sends aside) is a row of w.log, in w.log's order, and the flight wrote some.
    let logged: Vec<[u8; 4]> = w
        .iter()
        .map(|row| {
            let values: [u8; 4] = std::array::from_fn(|m| i2c_from_rad_s(row[m + 1]));
            map.speed_writes(&values).map(|(_, _, v)| v)
        })
        .collect();
    let mut written = speed_writes.clone();
    written.dedup();
    let stop = map.speed_writes(&[0; 4]).map(|(_, _, v)| v);
    let flight = written
        .iter()
        .skip_while(|c| **c == idle)
        .take_while(|c| **c != stop);
    let mut at_row = 0;
    let mut commands = 0;
    for c in flight {
        let found = logged[at_row..].iter().position(|l| l == c);
        let Some(i) = found else {
            panic!("{c:?} written but not in w.log after row {at_row}");
        };
        at_row += i;
        commands += 1;
    }
    assert!(
        commands * 2 > logged.len(),
        "{commands} of {} written",
        logged.len()
    );
    // 4. Shutdown: zero to every ESC, then disable every ESC, and nothing after.
    assert_ends_zero_then_disable(tx);
    assert_eq!(summary.esc_stop_reason.as_deref(), Some("shutdown"));

    // The run folder is self-contained and replays to identical bytes.
    for f in [
        "config.toml",
        "imu_calib.txt",
        "K_prop_full_ppzt.txt",
        "err.log",
        "imu_raw.log",
    ] {
        assert!(run_dir.join(f).is_file(), "{f} missing from the run folder");
    }
    let moved = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(&run_dir).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), moved.path().join(e.file_name())).unwrap();
    }
    let out = tempfile::tempdir().unwrap();
    let o = uquad(
        &root(),
        &[
            "replay",
            moved.path().to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "x_hat.log",
        "w.log",
        "int.log",
        "kalman_in.log",
        "innov.log",
    ] {
        let ours = std::fs::read(run_dir.join(f)).unwrap();
        let replayed = std::fs::read(out.path().join(f)).unwrap();
        assert!(!ours.is_empty());
        assert_eq!(ours, replayed, "{f}: the replay differs from the run");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_logger_loses_no_control_step() {
    let _one = ONE_AT_A_TIME.lock().await;
    // x_hat's logger stops writing for 500 ms a little after the flight starts; its queue holds
    // 8 records, so about 40 records cannot be queued.
    let stall = uquad::tasks::logger::LogStall {
        stream: uquad::logs::Stream::XHat,
        after_records: 20,
        not_before: None,
        duration: Duration::from_millis(500),
    };
    let (summary, _sent, _bus, _logs) = fly_for(
        &["log.queue_records=8"],
        Some(stall),
        tokio::time::sleep(Duration::from_millis(5_000)),
    )
    .await;
    assert!(summary.error.is_none(), "{:?}", summary.error);
    let run_dir = &summary.run_dir;
    let steps = summary.steps;
    assert!(steps > 100, "{steps}");
    // Every control step happened and was commanded and logged on the other streams. A
    // control path that waited on the stalled logger would drop most of its 500 ms (the
    // frames' queue holds 8); only a stall of the whole host, which the watchdog counts, may
    // drop or delay one or two.
    let text = summary.text();
    for (what, n) in [
        ("dropped", summary.dropped_frames),
        ("late", summary.late_feedback),
    ] {
        assert!(
            n == 0 || (summary.host_stalls > 0 && n * 100 <= steps),
            "{n} {what} of {steps} steps: {text}"
        );
    }
    assert_eq!(read_table(&run_dir.join("w.log")).len() as u64, steps);
    assert_eq!(
        read_table(&run_dir.join("kalman_in.log")).len() as u64,
        steps
    );
    // Newest command wins at the ESC writer: two frames decoded from one read can merge.
    assert!(
        summary.esc_commands * 10 >= steps * 9,
        "{} commands for {steps} steps",
        summary.esc_commands
    );
    // The stalled stream lost records, counted, and said so in err.log.
    let dropped = summary.log_drops[uquad::logs::Stream::XHat];
    assert!(dropped > 20, "dropped {dropped}");
    assert_eq!(summary.log_drops_total(), dropped);
    assert_eq!(
        read_table(&run_dir.join("x_hat.log")).len() as u64,
        steps - dropped
    );
    let err = std::fs::read_to_string(run_dir.join("err.log")).unwrap();
    assert!(
        err.contains(&format!("log stream x_hat: {dropped} records dropped")),
        "{err}"
    );
    assert!(summary.text().contains(&format!("x_hat {dropped}")));
    // The stall cost the control path nothing.
    assert_eq!(summary.deadline_misses, 0);
    assert!(summary.halt.is_none(), "{:?}", summary.halt);
}

/// `fly` with the pilot's radio on a pty as `rc.device`, opened as the board's UART is: SBUS
/// frames from a transmitter whose arm switch goes on once the pre-arm checks can pass (the
/// vehicle arms: the ESCs' start-up ramp on the mock bus) and whose kill switch then goes on
/// (every ESC zeroed and disabled, the stop named `kill`, the vehicle disarmed, the run going
/// on).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fly_arms_by_the_radios_switch_and_its_kill_switch_stops_the_escs() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
    use uquad::core::rc::sticks::{RcInput, Sticks};
    use uquad::core::rc::{RcFrame, RcProtocol, sbus};
    let _one = ONE_AT_A_TIME.lock().await;
    let (mut master, slave) = serialport::TTYPort::pair().expect("a pty pair");
    let path = serialport::SerialPort::name(&slave).expect("the pty's name");
    let port = uquad::hw::serial::open_rc(std::path::Path::new(&path), RcProtocol::Sbus)
        .expect("the pty opens as a receiver's UART");
    // The 2012 profile, waiting for `arm`: it calibrates with the motors idling, after it.
    let sets = ["commander.start=\"disarmed\"", "rc.protocol=\"sbus\""];
    let sets: Vec<&str> = FLY_TOLERANT.iter().chain(&sets).copied().collect();
    let cfg = uquad::config::load(&profile_2012(), &common::sets(&sets))
        .expect("the profile")
        .config;
    // 0: switches off; 1: the arm switch on; 2: the kill switch on too.
    let state = Arc::new(AtomicU8::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let writer = std::thread::spawn({
        let (state, stop, map) = (state.clone(), stop.clone(), cfg.rc.map());
        move || {
            use std::io::Write;
            while !stop.load(Ordering::Relaxed) {
                let s = state.load(Ordering::Relaxed);
                let input = RcInput {
                    sticks: Sticks {
                        throttle: -1.0,
                        ..Sticks::default()
                    },
                    arm: s >= 1,
                    kill: s >= 2,
                    mode: 0,
                };
                let frame = sbus::encode(&RcFrame {
                    channels: map.frame_for(&input),
                    frame_lost: false,
                    failsafe: false,
                });
                if master.write_all(&frame).is_err() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(7));
            }
        }
    });
    let switches = state.clone();
    let (summary, _sent, bus, _logs) = fly_with_rc(
        &sets,
        uquad::app::fly::FlyOptions::default(),
        Link::Pty,
        Box::new(|_, f| Some(f)),
        Some(Box::new(port)),
        |bus: uquad::hw::esc_bus::MockBus| async move {
            // A second of steady frames, then the arm switch; the ESCs' ramp, then the kill
            // switch.
            tokio::time::sleep(Duration::from_millis(3_000)).await;
            switches.store(1, Ordering::Relaxed);
            let t0 = std::time::Instant::now();
            while !bus.transactions().iter().any(|t| t.reg == REG_ENABLE)
                && t0.elapsed() < Duration::from_secs(10)
            {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            tokio::time::sleep(Duration::from_millis(3_000)).await;
            switches.store(2, Ordering::Relaxed);
            tokio::time::sleep(Duration::from_millis(1_000)).await;
        },
    )
    .await;
    stop.store(true, Ordering::Relaxed);
    let _ = writer.join();
    let text = summary.text();
    assert!(summary.error.is_none(), "{:?}: {text}", summary.error);
    assert!(
        summary.halt.is_none(),
        "the kill switch is not a halt: {text}"
    );
    let mode_log = std::fs::read_to_string(summary.run_dir.join("mode.log")).unwrap();
    assert!(mode_log.contains(" in rc arm | ok"), "{mode_log}");
    assert!(
        mode_log.contains(" mode disarmed kill switch"),
        "{mode_log}"
    );
    let rc = summary.rc.expect("the receiver's counts");
    assert!(rc.frames > 500 && rc.rejected_frames == 0, "{rc:?}");
    // Armed: the ESCs enabled and ramped; killed: zeroed and disabled, the stop confirmed
    // and named, and nothing written after it.
    let tx = bus.transactions();
    assert!(
        tx.iter().any(|t| t.reg == REG_ENABLE),
        "never armed: {text}"
    );
    assert!(tx.iter().any(|t| t.reg == REG_SPEED && t.value > 0));
    // After the last speed: zero to every ESC, then disable; from then on only the
    // disarmed vehicle's probes (disables), never an enable or a speed.
    let last = tx
        .iter()
        .rposition(|t| t.reg == REG_SPEED && t.value > 0)
        .expect("speeds written");
    assert_ends_zero_then_disable(&tx[..last + 9]);
    assert!(tx[last + 9..].iter().all(|t| t.reg == REG_DISABLE));
    assert_eq!(summary.esc_stop_reason.as_deref(), Some("kill"), "{text}");
}
