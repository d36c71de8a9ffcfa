//! The ground-station link task: MAVLink 2 over UDP or a serial radio, on the main runtime and
//! never on the control path. The protocol is `crate::gcs`; this task moves its messages.
//!
//! In: frames from the link, at most `gcs.max_rx_per_s` a second (beyond: dropped, counted);
//! the flight's notices (mode changes, failsafes, refusals, commands' outcomes) from a queue
//! the control path only `try_send`s into; its newest step, GPS fix, log folder probe and
//! watchdog status.
//! Out: operator inputs (commands; the ground station's heartbeats as link beats) into the
//! flight's bounded operator queue, never waited on (a full queue refuses the command);
//! telemetry, acknowledgements and texts to the link (a full link drops and counts).
//! Rate: a tick every 20 ms sends what is due. Ends: on cancel.
//!
//! - `state`: the task's state, the bytes heard, the notices, the tick and health;
//! - `commands`: commands to the commander and their acknowledgements;
//! - `streams`: the periodic messages and requests for one;
//! - `params`: the parameter protocol; `store`: keeping a set value;
//! - `mission`: the mission protocol (upload, download, progress); `mission_state`: its state;
//! - `link`: the UDP socket or the serial radio.

mod commands;
mod link;
mod mission;
mod mission_state;
mod params;
mod state;
mod store;
mod streams;

pub use link::Link;
pub use mission_state::MissionDesk;
pub use state::GcsContext;
pub use store::ParamStore;

use std::sync::{Arc, Mutex};
use std::time::Duration;

/// How often the task looks at what is due.
const TICK: Duration = Duration::from_millis(20);

/// The link's part of the run's report; the task publishes it after each thing it handles.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct GcsReport {
    #[serde(flatten)]
    pub rx: crate::gcs::wire::RxCounts,
    /// Frames over `gcs.max_rx_per_s`, and datagrams over its bytes, dropped unread.
    pub flood_drops: u64,
    pub rx_errors: u64,
    pub tx_frames: u64,
    pub tx_drops: u64,
    pub commands: u64,
    pub commands_refused: u64,
    /// Commands, parameter sets and mission writes from a sender that may not command (not
    /// a ground station, or not in `gcs.allowed_systems`): denied.
    pub senders_denied: u64,
    /// Inputs the flight's full operator queue could not take.
    pub input_drops: u64,
    pub param_sets: u64,
    /// Notices the flight's full queue dropped before the link read them.
    pub notices_missed: u64,
    pub gcs_heartbeats: u64,
    /// The task's CPU time, ms, and its share of one core over its run, %.
    pub cpu_ms: f64,
    pub cpu_pct: f64,
}

/// Where the task publishes its report.
pub type GcsStats = Arc<Mutex<GcsReport>>;

/// Serves the link until cancel.
pub async fn run(mut link: Link, ctx: GcsContext) {
    let streams = streams::default_streams(&ctx.cfg, std::time::Instant::now());
    let mut g = state::Gcs::new(ctx, link.decoder(), streams, link.params_per_tick());
    let mut notices = g.take_notices();
    let mut designed = g.missions.take_designed();
    let mut buf = vec![0u8; 4096];
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let cancel = g.cancel();
    loop {
        // Cancel, then the tick and the flight's notices before the link's bytes: a link
        // that never goes quiet (a flood) must not starve telemetry and acknowledgements.
        tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            _ = tick.tick() => g.timed(|g| {
                // The notices already sent first: the tick reads the flight's newest step,
                // and a step's notices (the last item reached, at touchdown) are sent before
                // the step is published; read after, a finished mission would show as not
                // started for a tick.
                while let Ok(n) = notices.try_recv() {
                    g.on_notice(n, &mut link);
                }
                g.on_tick(&mut link)
            }),
            Some(n) = notices.recv() => g.timed(|g| g.on_notice(n, &mut link)),
            Some(d) = designed.recv() => g.timed(|g| g.on_designed(d, &mut link)),
            r = link.recv(&mut buf) => match r {
                Ok((n, from)) => g.timed(|g| g.on_bytes(&buf[..n], from, &mut link)),
                // A datagram refused on the way (ICMP): nothing to read, go on.
                Err(_) if !link.is_serial() => g.timed(|g| g.count_rx_error()),
                Err(e) => {
                    tracing::error!("gcs: the serial radio failed ({e}); the link is closed");
                    break;
                }
            },
        }
    }
    // The run ends: what the flight said last (a halt, the kill) still reaches the ground
    // station, with a last heartbeat.
    g.timed(|g| g.on_end(&mut notices, &mut link));
}

/// The calling thread's CPU time, ns.
fn thread_cpu_ns() -> u64 {
    clock_ns(libc::CLOCK_THREAD_CPUTIME_ID)
}

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into `ts` only.
    if unsafe { libc::clock_gettime(clock, &mut ts) } != 0 {
        return 0;
    }
    (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64
}

/// The CPU clock of a running thread (for the control thread's load).
pub fn thread_clock<T>(handle: &std::thread::JoinHandle<T>) -> Option<libc::clockid_t> {
    use std::os::unix::thread::JoinHandleExt;
    let mut clock: libc::clockid_t = 0;
    // SAFETY: the thread is joinable (not yet joined), so its pthread_t is valid; the call
    // writes the clock id into `clock` only.
    let rc = unsafe { libc::pthread_getcpuclockid(handle.as_pthread_t(), &mut clock) };
    (rc == 0).then_some(clock)
}
