//! The operator's side of a `fly` run, all on the main runtime and never on the control path:
//! signals, the stdin keys, the console's statistics line, systemd's readiness and watchdog
//! pings.

use super::RunHandles;
use crate::core::commander::{LinkSource, OperatorInput};
use crate::core::status::VehicleStatus;
use crate::tasks::esc_writer::EscMailbox;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// The console's statistics line: latency histogram, deadline misses, log drops, the current
/// estimate and motor speeds.
pub(super) fn console_stats(h: &RunHandles, status: &VehicleStatus) -> String {
    // Latency histogram of the last second's commands (at most 100), in buckets of 100 µs,
    // and where it went: each stage's median and maximum over the same commands.
    let latency = &h.esc_status.latency;
    let mut hist = [0u32; 6];
    for v in latency.total.recent(100) {
        hist[(v as usize / 100).min(5)] += 1;
    }
    let [e, c, w] = latency.stages.each_ref().map(|s| s.recent_median_max(100));
    let mut s = format!(
        "stats t={:.1}s frames={} deadline_misses={} log_drops={} latency_us[<100,<200,<300,<400,<500,>=500]={:?} \
         latency_stages_us[estimate,command,write](median/max)=[{}/{}, {}/{}, {}/{}]",
        h.beats.us(Instant::now()) as f64 / 1e6,
        status.imu_frames,
        h.wd_status.deadline_misses.load(Ordering::Relaxed),
        h.logs.dropped().total(),
        hist,
        e.0,
        e.1,
        c.0,
        c.1,
        w.0,
        w.1
    );
    if let Some(l) = status.live {
        let _ = std::fmt::Write::write_fmt(
            &mut s,
            format_args!(
                " step={} z={:.3} setpoint_z={:.2} roll={:+.3} pitch={:+.3} yaw={:+.3} w=[{:.1}, {:.1}, {:.1}, {:.1}]",
                l.step,
                l.x[2],
                l.setpoint_m[2],
                l.x[3],
                l.x[4],
                l.x[5],
                l.w_rad_s[0],
                l.w_rad_s[1],
                l.w_rad_s[2],
                l.w_rad_s[3]
            ),
        );
    }
    if let Some(reason) = status.halt {
        let _ = std::fmt::Write::write_fmt(&mut s, format_args!(" HALT={}", reason.name()));
    }
    if let Some(rc) = status.rc {
        s += &rc.words();
    }
    s
}

/// READY=1 after the first IMU frame; WATCHDOG=1 every half `WatchdogSec` while the internal
/// watchdog checks and has not tripped; the pings stop for good at a trip.
pub(super) async fn notify_systemd(n: Arc<crate::hw::notify::Notifier>, h: RunHandles) {
    let poll = Duration::from_millis(10);
    while h.imu_stats.frames.load(Ordering::Relaxed) == 0 {
        tokio::select! {
            _ = h.cancel.cancelled() => return,
            _ = tokio::time::sleep(poll) => {}
        }
    }
    n.send("READY=1\nSTATUS=IMU frames arriving");
    let Some(every) = crate::hw::notify::watchdog_interval() else {
        return;
    };
    loop {
        tokio::select! {
            _ = h.cancel.cancelled() => return,
            _ = tokio::time::sleep(every) => {}
        }
        if let Some(halt) = h.wd_status.halt() {
            n.send(&format!("STATUS=halted: {}", halt.trip.reason.name()));
            return;
        }
        let now_us = h.beats.us(Instant::now());
        let checked_us = h.wd_status.last_check_us.load(Ordering::Relaxed);
        // A watchdog that has not checked for 100 ms is not healthy either.
        if now_us - checked_us < 100_000 {
            n.send("WATCHDOG=1");
        }
    }
}

/// The terminal `fly` runs in: lines typed on stdin (commands, `quit`, manual keys; see
/// [`OperatorInput::parse_line`]); Esc alone on a line quits (an arrow key's escape sequence
/// in a line is no quit). While stdin is an open terminal, a link beat each second: the
/// terminal is an operator link (`failsafe.link_sources`), lost when its ssh session drops.
pub(super) async fn read_terminal(tx: mpsc::Sender<OperatorInput>, cancel: CancellationToken) {
    use tokio::io::AsyncReadExt;
    let mut stdin = tokio::io::stdin();
    let mut byte = [0u8; 1];
    let mut line = Vec::with_capacity(64);
    let mut rate = crate::console::RateLimit::default();
    let mut beat = tokio::time::interval(Duration::from_secs(1));
    // Only a terminal is a link: stdin from /dev/null (a service) or a file is not.
    let is_terminal = std::io::IsTerminal::is_terminal(&std::io::stdin());
    loop {
        let n = tokio::select! {
            _ = cancel.cancelled() => return,
            _ = beat.tick(), if is_terminal => {
                let _ = tx.try_send(OperatorInput::Beat(LinkSource::Terminal));
                continue;
            }
            r = stdin.read(&mut byte) => match r {
                Ok(n) => n,
                Err(_) => return,
            },
        };
        if n == 0 {
            return;
        }
        let text = match byte[0] {
            b'\n' => String::from_utf8_lossy(&std::mem::take(&mut line)).into_owned(),
            // Bytes past the console's line cap are dropped (the line then reads as an error).
            b if line.len() < crate::console::MAX_LINE_BYTES => {
                line.push(b);
                continue;
            }
            _ => continue,
        };
        if !send_line(&text, &tx, &mut rate).await {
            return;
        }
    }
}

/// One typed line to the flight; `false` once the flight is gone.
async fn send_line(
    text: &str,
    tx: &mpsc::Sender<OperatorInput>,
    rate: &mut crate::console::RateLimit,
) -> bool {
    let inputs = match OperatorInput::parse_line(text, LinkSource::Terminal) {
        Ok(i) => i,
        Err(e) => {
            tracing::warn!("stdin: {e}");
            return true;
        }
    };
    for input in inputs {
        if !rate.allows(Instant::now()) {
            tracing::warn!(
                "stdin: more than {} commands a second; {input:?} refused",
                crate::console::MAX_COMMANDS_PER_S
            );
            continue;
        }
        if tx.send(input).await.is_err() {
            return false;
        }
    }
    true
}

/// Forwards another source's inputs (the simulator's scripted operator) until it ends.
pub(super) async fn forward(
    mut from: mpsc::Receiver<OperatorInput>,
    to: mpsc::Sender<OperatorInput>,
    cancel: CancellationToken,
) {
    loop {
        let input = tokio::select! {
            _ = cancel.cancelled() => return,
            i = from.recv() => match i {
                Some(i) => i,
                None => return,
            },
        };
        if to.send(input).await.is_err() {
            return;
        }
    }
}

/// The signals that end a run, and those that must not stop the process while the motors
/// are enabled (a stopped process cannot stop its motors).
const STOP_SIGNALS: [(&str, i32); 4] = [
    ("SIGINT", libc::SIGINT),
    ("SIGTERM", libc::SIGTERM),
    ("SIGHUP", libc::SIGHUP),
    ("SIGQUIT", libc::SIGQUIT),
];
const IGNORED_SIGNALS: [(&str, i32); 3] = [
    ("SIGTSTP", libc::SIGTSTP),
    ("SIGTTIN", libc::SIGTTIN),
    ("SIGTTOU", libc::SIGTTOU),
];

/// SIGINT, SIGTERM, SIGHUP (the ssh link of `fly`'s terminal dropped) and SIGQUIT: the first
/// zeroes and disables the motors and ends the run in order; a second is noted (the orderly
/// stop goes on: motors, then the report and the logs); a third exits once the motors' stop
/// has settled, skipping the logs' drain. SIGTSTP, SIGTTIN and SIGTTOU (a suspend key, a
/// read of the terminal from the background) are ignored for the whole run.
pub(super) async fn handle_signals(
    mailbox: Arc<EscMailbox>,
    esc: Arc<crate::tasks::esc_writer::EscStatus>,
    mut logs: Option<crate::tasks::logger::LogHub>,
    cancel: CancellationToken,
    settle: Duration,
) {
    use tokio::signal::unix::{Signal, SignalKind, signal};
    let listen = |list: &[(&'static str, i32)]| -> Option<Vec<(&'static str, Signal)>> {
        list.iter()
            .map(|&(name, n)| signal(SignalKind::from_raw(n)).ok().map(|s| (name, s)))
            .collect()
    };
    let (Some(mut stop), Some(mut ignored)) = (listen(&STOP_SIGNALS), listen(&IGNORED_SIGNALS))
    else {
        tracing::error!("cannot install signal handlers");
        return;
    };
    let mut stops = 0;
    loop {
        let (name, stopping) = tokio::select! {
            n = next(&mut stop) => (n, true),
            n = next(&mut ignored) => (n, false),
            // The loggers end once every sender is gone: this one goes with the run.
            _ = cancel.cancelled(), if logs.is_some() => {
                logs = None;
                continue;
            }
        };
        if !stopping {
            tracing::warn!("{name} ignored: the motors are under this program's control");
            continue;
        }
        stops += 1;
        match stops {
            1 => {
                tracing::info!("{name}: stopping the motors and ending the run");
                if let Some(l) = logs.take() {
                    l.err(format!(
                        "signal {name}: stopping the motors and ending the run"
                    ));
                }
                mailbox.shutdown();
                cancel.cancel();
            }
            2 => tracing::warn!(
                "{name}: already stopping (motors first, then the report and logs); a third signal exits once the motors are stopped"
            ),
            _ => {
                wait_for_motor_stop(&esc, settle).await;
                tracing::warn!("{name}: exiting without draining the logs");
                std::process::exit(130);
            }
        }
    }
}

/// The name of the first of `signals` to arrive.
async fn next(signals: &mut [(&'static str, tokio::signal::unix::Signal)]) -> &'static str {
    std::future::poll_fn(|cx| {
        for (name, s) in signals.iter_mut() {
            if s.poll_recv(cx).is_ready() {
                return std::task::Poll::Ready(*name);
            }
        }
        std::task::Poll::Pending
    })
    .await
}

/// Waits until the ESC writer's stop has settled (confirmed, or out of retries), at most
/// `settle`.
async fn wait_for_motor_stop(esc: &crate::tasks::esc_writer::EscStatus, settle: Duration) {
    let asked = Instant::now();
    while esc.stop_outcome().is_none() && asked.elapsed() < settle {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// Shuts the ESC writer down (zero, disable, end) when dropped; idempotent.
pub(super) struct StopEscOnDrop(pub(super) Arc<EscMailbox>);

impl Drop for StopEscOnDrop {
    fn drop(&mut self) {
        self.0.shutdown();
    }
}
