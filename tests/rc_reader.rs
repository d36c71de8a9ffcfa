//! The RC receiver reader as `fly` runs it: SBUS frames written into a pty that the reader
//! opens with tokio-serial as it opens the board's UART, the real ESC writer thread on a
//! mock I2C bus. The arm switch's move reaches the flight's operator queue as `arm`; a frame
//! with the kill switch on reaches the ESC writer before any control step: every ESC is
//! zeroed and disabled and the stop confirmed, named `kill`. The time from the frame's write
//! to the confirmed stop is measured over `UQUAD_RC_TRIALS` kills (default 2; the closing
//! figures are a 20-trial run) and printed, not judged: it is the host's.

use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};
use uquad::config::{Config, RcProtocol};
use uquad::core::commander::{Command, LinkSource, OperatorInput};
use uquad::core::esc::{EscPhase, StopReason};
use uquad::core::rc::link::RcLink;
use uquad::core::rc::sticks::{RcInput, Sticks};
use uquad::core::rc::{Decoder, RcFrame, sbus};
use uquad::hw::esc_bus::MockBus;
use uquad::tasks::esc_writer::{EscMailbox, EscParams, EscStatus};
use uquad::tasks::heartbeats::Heartbeats;
use uquad::tasks::rc_reader::{RcReader, RcStats};

fn trials() -> usize {
    std::env::var("UQUAD_RC_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2)
}

/// The SBUS frame of a transmitter with the arm and kill switches as given.
fn frame(cfg: &Config, arm: bool, kill: bool) -> [u8; sbus::FRAME_LEN] {
    let input = RcInput {
        sticks: Sticks {
            throttle: -1.0,
            ..Sticks::default()
        },
        arm,
        kill,
        mode: 0,
    };
    sbus::encode(&RcFrame {
        channels: cfg.rc.map().frame_for(&input),
        frame_lost: false,
        failsafe: false,
    })
}

/// Waits up to `limit` for `done`, polling every millisecond.
fn wait(limit: Duration, mut done: impl FnMut() -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    done()
}

/// The reader runs on its own runtime, as in `fly`; this thread writes the receiver's frames
/// and waits on the ESC writer's status (blocking: it is not a runtime's).
#[test]
fn the_arm_switch_reaches_the_flight_and_the_kill_switch_stops_the_escs_at_its_frame() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("a runtime");
    let _in_rt = rt.enter();
    let cfg = Config {
        rc: uquad::config::RcConfig {
            protocol: RcProtocol::Sbus,
            ..Default::default()
        },
        ..Config::default()
    };
    let (mut master, slave) = serialport::TTYPort::pair().expect("a pty pair");
    let slave_path = serialport::SerialPort::name(&slave).expect("the pty's name");
    // The reader opens the pty by its path, as fly opens rc.device.
    let port = uquad::hw::serial::open_rc(std::path::Path::new(&slave_path), RcProtocol::Sbus)
        .expect("the pty opens as an SBUS UART");
    let beats = Arc::new(Heartbeats::new(Instant::now()));
    let (mailbox, status) = (
        Arc::new(EscMailbox::default()),
        Arc::new(EscStatus::default()),
    );
    let bus = MockBus::new();
    let params = EscParams {
        map: uquad::core::motor::MotorMap::UQUAD,
        timing: cfg.esc_timing(),
    };
    let writer = uquad::tasks::esc_writer::spawn(
        Box::new(bus.clone()),
        params,
        mailbox.clone(),
        status.clone(),
        beats.clone(),
        false,
    )
    .expect("the ESC writer starts");
    let (tx, mut rx) = tokio::sync::mpsc::channel(256);
    let stats = Arc::new(RcStats::default());
    let reader = RcReader {
        decoder: Decoder::Sbus(sbus::SbusDecoder::new()),
        link: RcLink::new(
            cfg.rc.map(),
            cfg.rc.modes.clone(),
            cfg.failsafe.rc_timeout_s,
        ),
        mailbox: mailbox.clone(),
        operator: tx,
        beats: beats.clone(),
        stats: stats.clone(),
        esc: status.clone(),
        kill: uquad::tasks::rc_reader::KillWatch::Off,
        frame_at: None,
    };
    let cancel = tokio_util::sync::CancellationToken::new();
    let task = rt.spawn(reader.run(port, cancel.clone()));

    // The arm switch off, then on: `arm` from the radio.
    for arm in [false, false, true, true] {
        master.write_all(&frame(&cfg, arm, false)).unwrap();
        std::thread::sleep(Duration::from_millis(7));
    }
    let mut inputs = Vec::new();
    let arm = OperatorInput::Command(Command::Arm, LinkSource::Rc);
    let armed = wait(Duration::from_secs(5), || {
        while let Ok(i) = rx.try_recv() {
            inputs.push(i);
        }
        inputs.contains(&arm)
    });
    assert!(armed, "no arm from the switch; inputs {inputs:?}");

    let mut latencies_ms = Vec::new();
    for trial in 0..trials() {
        // The motors running (the start-up ramp done), then the kill switch's frame.
        mailbox.start();
        let running = wait(Duration::from_secs(10), || {
            status.phase() == EscPhase::Running
        });
        assert!(running, "trial {trial}: the ESCs never ran");
        let written = bus.transactions().len();
        let sent = Instant::now();
        master.write_all(&frame(&cfg, true, true)).unwrap();
        let stopped = wait(Duration::from_secs(5), || {
            status.phase() == EscPhase::Stopped && status.stop_outcome().is_some()
        });
        assert!(stopped, "trial {trial}: no stop after the kill frame");
        let outcome = status.stop_outcome().unwrap();
        assert!(outcome.confirmed(), "trial {trial}: {outcome:?}");
        assert_eq!(status.stop_reason(), Some(StopReason::KillSwitch));
        let settled = beats.start() + Duration::from_micros(outcome.settled_us as u64);
        latencies_ms.push(settled.saturating_duration_since(sent).as_secs_f64() * 1e3);
        // Zero, then disable, to every ESC, after the kill frame.
        let tx_after = &bus.transactions()[written..];
        for a in uquad::core::motor::MotorMap::UQUAD.addresses {
            let mine: Vec<(u8, u8)> = tx_after
                .iter()
                .filter(|t| t.addr == a)
                .map(|t| (t.reg, t.value))
                .collect();
            let zero = mine.iter().position(|&(r, v)| r == 0xA2 && v == 0);
            let disable = mine.iter().rposition(|&(r, _)| r == 0xA1);
            assert!(zero.is_some() && disable > zero, "0x{a:02x}: {mine:?}");
        }
        // Off again, for the next trial: the stop was the pilot's, the ESCs may start again.
        master.write_all(&frame(&cfg, true, false)).unwrap();
        std::thread::sleep(Duration::from_millis(20));
    }
    latencies_ms.sort_by(f64::total_cmp);
    let pct = |p: f64| latencies_ms[((latencies_ms.len() - 1) as f64 * p).round() as usize];
    eprintln!(
        "kill switch, frame written to stop confirmed over {} trials: median {:.2} ms, max {:.2} ms",
        latencies_ms.len(),
        pct(0.5),
        latencies_ms.last().copied().unwrap_or(f64::NAN)
    );
    cancel.cancel();
    let _ = rt.block_on(task);
    mailbox.shutdown();
    let _ = writer.join();
    assert!(stats.frames.load(std::sync::atomic::Ordering::Relaxed) >= 4);
    // The reader timed each kill itself, from its frame's read to the confirmed stop (the
    // figure `sim --realtime` reports).
    let kills = stats.kills();
    assert_eq!(kills.len(), trials(), "{kills:?}");
    assert!(
        kills.iter().all(|k| k.confirmed_us >= k.frame_us),
        "{kills:?}"
    );
}
