//! Phase 5's ground-station link: opens it (a link that cannot open is logged and the run
//! flies without it, as with the console) and starts its task on the main runtime. `fly`,
//! `sim --realtime` and `sim --mode paced` start it the same way.

use super::{FlyOptions, RunHandles};
use crate::config::ParamStore;
use crate::config::Profile;
use crate::core::commander::OperatorInput;
use crate::gcs::params::Params;
use crate::tasks::gcs::{self, GcsContext, GcsStats, Link};
use crate::tasks::logger::LogHub;
use crate::tasks::notices::{Notice, Notices};
use crate::tasks::status::StatusReader;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// What the link takes from the run beyond the shared handles.
pub(crate) struct Inputs {
    pub operator: mpsc::Sender<OperatorInput>,
    pub notices: mpsc::Receiver<Notice>,
    pub status: StatusReader,
}

/// The run the link serves: its folder, logs and clock, the notices' sending side (for its
/// count of drops), where its report goes, and its end.
pub(crate) struct LinkRun {
    pub run_dir: PathBuf,
    pub logs: LogHub,
    pub notices: Notices,
    pub boot: Instant,
    pub stats: GcsStats,
    pub cancel: CancellationToken,
}

/// The flight's notices for the link, when it is served: the sending side for the control
/// path, and the queue.
pub(crate) fn notices(served: bool) -> (Notices, Option<mpsc::Receiver<Notice>>) {
    if !served {
        return (Notices::default(), None);
    }
    let (tx, rx) = Notices::channel();
    (tx, Some(rx))
}

pub(super) fn spawn(
    profile: &Profile,
    opts: &FlyOptions,
    h: &RunHandles,
    i: Inputs,
) -> tokio::task::JoinHandle<()> {
    let run = LinkRun {
        run_dir: h.run_dir.clone(),
        logs: h.logs.clone(),
        notices: h.notices.clone(),
        boot: h.beats.start(),
        stats: h.gcs_stats.clone().unwrap_or_default(),
        cancel: h.cancel.clone(),
    };
    start(profile, opts.log_dir.as_deref(), run, i)
}

/// Starts the link's task for `run`; kept parameters go beside the logs under `log_dir`.
pub(crate) fn start(
    profile: &Profile,
    log_dir: Option<&Path>,
    run: LinkRun,
    i: Inputs,
) -> tokio::task::JoinHandle<()> {
    let cfg = &profile.config;
    let ctx = GcsContext {
        cfg: cfg.gcs.clone(),
        params: Params::of(cfg),
        store: ParamStore {
            run_config: run.run_dir.join("config.toml"),
            profile: profile.path.clone(),
            kept_file: crate::config::kept_params_path(cfg, log_dir),
        },
        logs: run.logs.clone(),
        operator: i.operator,
        notices: i.notices,
        notices_tx: run.notices,
        status: i.status,
        gps_timeout_us: (cfg.control.gps_hold_timeout_s * 1e6).round() as i64,
        boot: run.boot,
        stats: run.stats,
        cancel: run.cancel,
        signing_key: profile.signing_key,
        takeoff_heights_m: {
            let heights = cfg.commander_params().height_range_m();
            (*heights.start(), *heights.end())
        },
        log_desk: log_desk(&run.run_dir),
        missions: Some(gcs::MissionDesk {
            profile: std::sync::Arc::new(profile.clone()),
            run_dir: run.run_dir,
            loaded: profile.mission.as_ref().map(|m| m.plan.clone()),
        }),
    };
    let logs = run.logs;
    tokio::spawn(async move {
        match Link::open(&ctx.cfg).await {
            Ok(link) => {
                let line = format!("ground-station link (MAVLink 2): {}", link.describe());
                tracing::info!("{line}");
                logs.err(line);
                gcs::run(link, ctx).await;
            }
            Err(e) => {
                tracing::error!("ground-station link: {e:#}; flying without it");
                logs.err(format!("ground-station link: {e:#}; flying without it"));
            }
        }
    })
}

/// The runs beside `run_dir` for log download, each as its ULog export (`uquad export`).
fn log_desk(run_dir: &Path) -> Option<gcs::LogDesk> {
    let dir = run_dir.parent()?.to_path_buf();
    let export: gcs::Export = std::sync::Arc::new(|run: &Path, out: &Path| {
        crate::app::export::run(run, crate::app::export::Format::Ulog, out)
            .map(|_| ())
            .map_err(|e| format!("{e:#}"))
    });
    Some(gcs::LogDesk::new(dir, run_dir.to_path_buf(), export))
}
