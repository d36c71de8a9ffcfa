//! The ground-station link task: MAVLink 2 over UDP or a serial radio, on the main runtime and
//! never on the control path. The protocol is `crate::gcs::connection`, which does no I/O;
//! this task moves its bytes, reads the vehicle's status for it, keeps its timer, and does
//! its file work (err.log lines, kept parameters, uploads planned on a blocking worker).
//!
//! In: bytes from the link; the flight's notices (a queue the control path only `try_send`s
//! into); the vehicle's status (`tasks::status`), read at each notice and each timer.
//! Out: operator inputs into the flight's bounded queue, never waited on (a full queue is
//! told back to the protocol, which refuses the command); frames to the link (a full link
//! drops and counts).
//! Rate: whenever the protocol's timer is due (20 ms at the fastest). Ends: on cancel, after a
//! last heartbeat; or when the serial radio fails.

mod link;
mod logs;

pub use link::Link;
pub use logs::{Export, LogDesk};

use crate::config::{GcsConfig, ParamStore, Profile};
use crate::core::commander::OperatorInput;
use crate::core::mission::MissionPlan;
use crate::gcs::connection::{Connection, Counts, Effect, MissionSettings, Notice, Settings};
use crate::gcs::params::Params;
use crate::hw::cpu_clock::thread_cpu_ns;
use crate::tasks::notices::Notices;
use crate::tasks::status::StatusReader;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// What the task is given: the link's settings, the flight's shared state, its queues.
pub struct GcsContext {
    pub cfg: GcsConfig,
    pub params: Params,
    pub store: ParamStore,
    /// The run's logs (err.log takes the link's lines).
    pub logs: crate::tasks::logger::LogHub,
    pub operator: mpsc::Sender<OperatorInput>,
    /// The flight's notices, and their sending side's count of what a full queue dropped.
    pub notices: mpsc::Receiver<Notice>,
    pub notices_tx: Notices,
    pub status: StatusReader,
    /// A fix older than this does not hold position, µs.
    pub gps_timeout_us: i64,
    /// The run's start.
    pub boot: Instant,
    pub stats: GcsStats,
    pub cancel: CancellationToken,
    /// Plans ground stations' missions (none: uploads are refused).
    pub missions: Option<MissionDesk>,
    /// MAVLink 2 signing's key (`gcs.signing_key_file`; none: off).
    pub signing_key: Option<crate::config::SigningKey>,
    /// The heights a takeoff may go to above the takeoff point, m.
    pub takeoff_heights_m: (f64, f64),
    /// Serves the runs' logs for download (none: an empty list).
    pub log_desk: Option<LogDesk>,
}

/// What the link needs to plan an upload: the profile (its checks, weights and speeds) and
/// the run folder the mission files go into; the mission loaded at start, if any.
pub struct MissionDesk {
    pub profile: Arc<Profile>,
    pub run_dir: PathBuf,
    pub loaded: Option<Arc<MissionPlan>>,
}

/// The link's part of the run's report; the task publishes it after each thing it handles.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct GcsReport {
    #[serde(flatten)]
    pub counts: Counts,
    /// Notices the flight's full queue dropped before the link read them.
    pub notices_missed: u64,
    /// The task's CPU time, ms, and its share of one core over its run, %.
    pub cpu_ms: f64,
    pub cpu_pct: f64,
}

/// Where the task publishes its report.
pub type GcsStats = Arc<Mutex<GcsReport>>;

/// What a blocking worker did for the protocol: planned upload `name`, listed the logs,
/// read one, or kept a parameter.
enum Done {
    Plan {
        name: String,
        plan: Result<MissionPlan, String>,
    },
    Logs(Result<Vec<crate::gcs::connection::LogEntry>, String>),
    Kept {
        index: usize,
        value: toml::Value,
        kept: Result<(), String>,
    },
    Log(u16, Result<Arc<[u8]>, String>),
}

/// The protocol's settings from the task's context and its link.
fn settings(ctx: &GcsContext, link: &Link, now: Instant) -> Settings {
    let since_boot_10us = now.saturating_duration_since(ctx.boot).as_micros() / 10;
    let at_boot = crate::gcs::signing::now().saturating_sub(since_boot_10us as u64);
    Settings {
        cfg: ctx.cfg.clone(),
        params: ctx.params.clone(),
        boot: ctx.boot,
        signing: ctx.signing_key.map(|k| (k.0, at_boot)),
        gps_timeout_us: ctx.gps_timeout_us,
        datagrams: !link.is_serial(),
        params_per_pace: link.params_per_tick(),
        takeoff_heights_m: ctx.takeoff_heights_m,
        missions: ctx.missions.as_ref().map(|d| MissionSettings {
            speed_m_s: d.profile.config.mission.speed_m_s,
            hover_z_m: d.profile.config.control.hover_z_m,
            loaded_items: d.loaded.as_ref().map(|p| p.mission.items.len()),
        }),
    }
}

/// What woke the task.
enum Wake {
    Timer,
    Notice(Notice),
    Done(Done),
    Bytes(usize, Option<std::net::SocketAddr>),
    RxError,
}

/// Serves the link until cancel.
pub async fn run(mut link: Link, mut ctx: GcsContext) {
    let started = Instant::now();
    let mut conn = Connection::new(settings(&ctx, &link, started), started);
    let (done_tx, mut done) = mpsc::channel::<Done>(2);
    let mut buf = vec![0u8; 4096];
    let mut cpu_ns = 0u64;
    // Far enough never to come; a protocol always has its health check due.
    let never = Instant::now() + Duration::from_secs(86_400);
    loop {
        let due = tokio::time::Instant::from_std(conn.poll_timeout().unwrap_or(never));
        // Cancel, then the timer and the flight before the link's bytes: a link that never
        // goes quiet (a flood) must not starve telemetry and acknowledgements.
        let wake = tokio::select! {
            biased;
            _ = ctx.cancel.cancelled() => break,
            _ = tokio::time::sleep_until(due) => Wake::Timer,
            Some(n) = ctx.notices.recv() => Wake::Notice(n),
            Some(d) = done.recv() => Wake::Done(d),
            r = link.recv(&mut buf) => match r {
                Ok((n, from)) => Wake::Bytes(n, from),
                // A datagram refused on the way (ICMP): nothing to read, go on.
                Err(_) if !link.is_serial() => Wake::RxError,
                Err(e) => {
                    tracing::error!("gcs: the serial radio failed ({e}); the link is closed");
                    break;
                }
            },
        };
        let t0 = thread_cpu_ns();
        if ctx.signing_key.is_some() {
            conn.set_signing_time(crate::gcs::signing::now());
        }
        match wake {
            Wake::Timer => {
                fresh_status(&mut conn, &mut ctx);
                conn.handle_timeout(Instant::now());
            }
            // A notice is the flight's news (a mode, an item reached): the status with it.
            Wake::Notice(n) => {
                conn.handle_notice(Instant::now(), n);
                fresh_status(&mut conn, &mut ctx);
            }
            Wake::Done(Done::Plan { name, plan }) => conn.handle_plan(Instant::now(), &name, plan),
            Wake::Done(Done::Logs(list)) => conn.handle_log_list(Instant::now(), list),
            Wake::Done(Done::Kept { index, value, kept }) => {
                conn.handle_param_kept(Instant::now(), index, &value, kept)
            }
            Wake::Done(Done::Log(id, bytes)) => conn.handle_log_opened(Instant::now(), id, bytes),
            Wake::Bytes(n, from) => {
                if conn.handle_datagram(Instant::now(), &buf[..n])
                    && let Some(f) = from
                {
                    link.heard_from(f);
                }
            }
            Wake::RxError => conn.count_rx_error(),
        }
        drive(&mut conn, &mut link, &ctx, &done_tx);
        cpu_ns += thread_cpu_ns().saturating_sub(t0);
        publish(&conn, &ctx, cpu_ns, started);
    }
    // The run ends: what the flight said last (a halt, the kill) still reaches the ground
    // station, with a last heartbeat.
    if ctx.signing_key.is_some() {
        conn.set_signing_time(crate::gcs::signing::now());
    }
    fresh_status(&mut conn, &mut ctx);
    conn.handle_end(Instant::now());
    drive(&mut conn, &mut link, &ctx, &done_tx);
    publish(&conn, &ctx, cpu_ns, started);
}

/// The vehicle's status, after the notices already sent: a step's notices (the last item
/// reached, at touchdown) are sent before the step is published; told after, a finished
/// mission would show as not started for a moment.
fn fresh_status(conn: &mut Connection, ctx: &mut GcsContext) {
    while let Ok(n) = ctx.notices.try_recv() {
        conn.handle_notice(Instant::now(), n);
    }
    conn.handle_status(Instant::now(), ctx.status.read());
}

/// Everything the protocol has for the outside: inputs to the flight, file work, frames (a
/// download's in the room the link has left).
fn drive(conn: &mut Connection, link: &mut Link, ctx: &GcsContext, done: &mpsc::Sender<Done>) {
    // File work first: a kept parameter's input for the flight follows it at once.
    while let Some(effect) = conn.poll_effect() {
        match effect {
            Effect::ErrLog(line) => ctx.logs.err(line),
            Effect::KeepParam {
                index,
                param,
                value,
                t_s,
            } => keep_param(ctx, index, param, value, t_s, done),
            Effect::PlanMission { name, text } => plan(ctx.missions.as_ref(), name, text, done),
            Effect::ListLogs => list_logs(ctx.log_desk.as_ref(), done),
            Effect::OpenLog { id } => read_log(ctx.log_desk.as_ref(), id, done),
        }
    }
    while let Some(input) = conn.poll_operator() {
        if let Err(e) = ctx.operator.try_send(input) {
            conn.handle_operator_full(Instant::now(), e.into_inner());
        }
    }
    transmit(conn, link);
    conn.poll_download(Instant::now(), link.download_room());
    transmit(conn, link);
}

fn transmit(conn: &mut Connection, link: &mut Link) {
    while let Some(frame) = conn.poll_transmit() {
        conn.count_sent(link.send(&frame).is_ok());
    }
}

/// Keeps a parameter on a blocking worker (it reads the configuration and syncs files to
/// the card: not on the link's task, which serves the flight's telemetry and commands), one
/// at a time; the outcome comes back through `done`.
fn keep_param(
    ctx: &GcsContext,
    index: usize,
    param: crate::gcs::params::Param,
    value: toml::Value,
    t_s: f64,
    done: &mpsc::Sender<Done>,
) {
    static KEEPING: Mutex<()> = Mutex::new(());
    let (store, logs, tx) = (ctx.store.clone(), ctx.logs.clone(), done.clone());
    tokio::task::spawn_blocking(move || {
        let _one = KEEPING.lock().unwrap_or_else(|p| p.into_inner());
        let kept = store.set(param.id, param.key, value.clone(), t_s).map(|k| {
            k.note_failed.into_iter().for_each(|why| logs.err(why));
            tracing::info!("{}", k.line);
            logs.err(k.line);
        });
        let _ = tx.blocking_send(Done::Kept { index, value, kept });
    });
}

/// Lists the logs on a blocking worker (exports take seconds); none without a desk.
fn list_logs(desk: Option<&LogDesk>, done: &mpsc::Sender<Done>) {
    let (desk, tx) = (desk.cloned(), done.clone());
    tokio::task::spawn_blocking(move || {
        let list = desk.map_or(Ok(Vec::new()), |d| d.list());
        let _ = tx.blocking_send(Done::Logs(list));
    });
}

/// Reads log `id` on a blocking worker.
fn read_log(desk: Option<&LogDesk>, id: u16, done: &mpsc::Sender<Done>) {
    let (desk, tx) = (desk.cloned(), done.clone());
    tokio::task::spawn_blocking(move || {
        let bytes = desk.map_or(Err("no logs are served".into()), |d| d.read(id));
        let _ = tx.blocking_send(Done::Log(id, bytes));
    });
}

/// Writes upload `name` into the run folder and plans it on a blocking worker, off this task
/// and off the control path; the plan comes back through `plans`.
fn plan(desk: Option<&MissionDesk>, name: String, text: String, done: &mpsc::Sender<Done>) {
    let Some(desk) = desk else {
        return;
    };
    let (profile, path, tx) = (desk.profile.clone(), desk.run_dir.join(&name), done.clone());
    tokio::task::spawn_blocking(move || {
        let plan = std::fs::write(&path, &text)
            .map_err(|e| format!("mission upload: cannot write {}: {e}", path.display()))
            .and_then(|()| profile.plan_mission(&path, &text));
        // A link that has ended takes no plan: nothing to tell.
        let _ = tx.blocking_send(Done::Plan { name, plan });
    });
}

/// The report, with the task's CPU time over its run so far.
fn publish(conn: &Connection, ctx: &GcsContext, cpu_ns: u64, started: Instant) {
    let wall_ns = started.elapsed().as_nanos().max(1) as f64;
    let report = GcsReport {
        counts: conn.counts(),
        notices_missed: ctx.notices_tx.dropped(),
        cpu_ms: cpu_ns as f64 / 1e6,
        cpu_pct: 100.0 * cpu_ns as f64 / wall_ns,
    };
    if let Ok(mut shared) = ctx.stats.lock() {
        *shared = report;
    }
}
