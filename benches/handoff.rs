//! The last stage of the frame → ESC write latency: a motor command's hand-off from the control
//! thread to the ESC writer thread and its bus write (a mock bus), with the writer told at the
//! frame's decode that a command follows (it spins for it, as in flight) and, for comparison,
//! asleep until the command arrives.

use criterion::{Criterion, criterion_group, criterion_main};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use uquad::core::esc::EscPhase;
use uquad::hw::esc_bus::MockBus;
use uquad::tasks::esc_writer::{self, EscMailbox, EscParams, EscStatus, MotorCommand};
use uquad::tasks::heartbeats::Heartbeats;
use uquad::tasks::latency::Stamps;

/// What the control thread computes between the decode and the command (the Kalman step and
/// the control law take about this long on this machine).
const COMPUTE: Duration = Duration::from_micros(20);

fn busy(d: Duration) {
    let until = Instant::now() + d;
    while Instant::now() < until {
        std::hint::spin_loop();
    }
}

/// Posts one command and waits until the writer has written it; returns command → write.
fn one_command(mailbox: &EscMailbox, status: &EscStatus, expect: bool) -> Duration {
    let written = status.commands.load(Ordering::SeqCst);
    let decoded = Instant::now();
    if expect {
        mailbox.expect_command();
    }
    busy(COMPUTE);
    let commanded = Instant::now();
    mailbox.command(MotorCommand {
        w_rad_s: [300.0; 4],
        stamps: Stamps {
            decoded,
            estimated: commanded,
            commanded,
        },
    });
    while status.commands.load(Ordering::SeqCst) == written {
        std::hint::spin_loop();
    }
    commanded.elapsed()
}

fn bench_handoff(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let profile = uquad::config::load(&root.join("config/uquad.toml"), &[])
        .unwrap_or_else(|e| panic!("the default profile loads: {e}"));
    let mailbox = Arc::new(EscMailbox::default());
    let status = Arc::new(EscStatus::default());
    let beats = Arc::new(Heartbeats::new(Instant::now()));
    let params = EscParams {
        map: profile.motor_map(),
        timing: profile.config.esc_timing(),
    };
    let writer = esc_writer::spawn(
        Box::new(MockBus::new()),
        params,
        mailbox.clone(),
        status.clone(),
        beats,
        // Realtime: SCHED_FIFO and the last CPU, which the writer needs to spin (as root or with
        // RLIMIT_RTPRIO; otherwise a warning, and both figures are of the sleeping hand-off).
        true,
    )
    .unwrap_or_else(|e| panic!("the writer thread starts: {e}"));
    mailbox.start();
    while status.phase() != EscPhase::Running {
        std::thread::sleep(Duration::from_millis(10));
    }
    for (name, expect) in [
        ("esc_handoff_writer_told_at_decode", true),
        ("esc_handoff_writer_asleep", false),
    ] {
        c.bench_function(name, |b| {
            b.iter_custom(|iters| {
                (0..iters)
                    .map(|_| {
                        // A pause as between frames: the writer parks again.
                        std::thread::sleep(Duration::from_micros(200));
                        one_command(&mailbox, &status, expect)
                    })
                    .sum()
            })
        });
    }
    mailbox.shutdown();
    let _ = writer.join();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(Duration::from_secs(3));
    targets = bench_handoff
}
criterion_main!(benches);
