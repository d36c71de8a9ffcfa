//! The `uquad` command: parses the command line, sets up tracing, loads the configuration and
//! dispatches to the modes in `uquad::app`.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use uquad::config;

#[derive(Parser, Debug)]
#[command(
    name = "uquad",
    version,
    about = "Flight software for the uQuad quadcopter",
    long_about = "Flight software for the uQuad quadcopter: IMU measurement path, 15-state EKF, \
hover controller and motor drivers, with a replay mode that reruns a recorded flight.\n\n\
Logging goes to stderr; set RUST_LOG (e.g. RUST_LOG=debug) to change its level.",
    after_help = "Examples:\n  \
uquad check-config config/flight-2012-05.toml --set vehicle.mass_kg=1.6\n  \
uquad replay tests/data/flight-2012-05-25 --config config/flight-2012-05.toml --out /tmp/replay"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Validate a configuration and the files it names; print every problem found.
    #[command(
        long_about = "Validate a configuration file and the calibration and gain files it names.\n\n\
Exits 0 when everything is valid. Otherwise prints one line per problem, naming the file, the key \
(or the position of a malformed number in a data file) and the problem, and exits 1."
    )]
    CheckConfig {
        /// The configuration file (TOML), e.g. config/uquad.toml.
        file: PathBuf,
        #[command(flatten)]
        sets: SetArgs,
    },
    /// Fly: the flight program (serial IMU, EKF, controller, ESCs over I2C, loggers).
    #[command(long_about = "Fly: the flight program the BeagleBoard runs.\n\n\
Opens the IMU on imu.device (115200 8N1 raw) and the ESCs on esc.bus (Linux I2C). Start-up: \
wait for a stable IMU sampling period (motors off), run the ESC start-up ramp, calibrate the IMU \
(512 frames, motors idling), ramp the motors up over 100 steps, then hover at control.hover_z_m. \
Logs go to <log dir>/<run-id>/ (imu_raw, kalman_in, x_hat, w, int, gps, err, and the resolved \
config.toml with copies of its data files, so `uquad replay <run folder>` reruns it).\n\n\
SIGINT/SIGTERM zero and disable the motors, then the logs are flushed; a second signal exits at \
once. The original's manual-mode keys work from stdin (j/g roll, y/h pitch, q/w yaw, e/d \
altitude, i/k mass, 0 reset mass, ESC quit).")]
    Fly {
        /// Configuration profile (default: config/uquad.toml under the working directory).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        #[command(flatten)]
        sets: SetArgs,
        /// Folder under which the run folder is created (default: log.dir of the profile).
        #[arg(long, value_name = "DIR")]
        log_dir: Option<PathBuf>,
        /// Write the flight report (JSON: frames, steps, latency_us {p50, p99, max},
        /// deadline_misses, log_drops, watchdog_trips, halt, run_dir) to FILE at the end.
        #[arg(long, value_name = "FILE")]
        report: Option<PathBuf>,
    },
    /// Simulate: fly the real code against a physics model of the uQuad (the main job).
    #[command(
        long_about = "Simulate: fly the real code against a physics model of the uQuad.\n\n\
The simulated IMU sends real 30-byte frames (raw counts from the true state through the \
inverted calibration, with noise), the simulated ESCs take the real I2C register writes, and \
the flight goes through settle, ESC start-up ramp, IMU calibration, flight ramp and hover, as \
`fly` does. With gps.mode = \"gpsd\" (the default profile) a fix of the true position reaches \
the filter each simulated second, where `fly` would read gpsd. The run folder logs/<run-id>/ is written as `fly` writes it, so \
`uquad replay <run folder> --out DIR` reruns it to identical bytes.\n\n\
--fast (the default) runs the flight's state machines in lock-step with the physics on a \
simulated clock: 40 simulated seconds take well under a second. --realtime runs fly's own \
tasks and threads against the simulated edges, paced by the wall clock.\n\n\
With no arguments: config/uquad.toml, sim.duration_s (40 s), a summary at the end."
    )]
    Sim {
        /// Configuration profile (default: config/uquad.toml under the working directory).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        #[command(flatten)]
        sets: SetArgs,
        /// Simulated seconds, start-up included (default: sim.duration_s).
        #[arg(long, value_name = "S")]
        duration: Option<f64>,
        /// Pace the simulation to the wall clock, running fly's tasks and threads.
        #[arg(long, conflicts_with = "fast")]
        realtime: bool,
        /// Run on a simulated clock, as fast as the machine can (the default).
        #[arg(long)]
        fast: bool,
        /// Seed of every random draw (default: sim.seed).
        #[arg(long, value_name = "N")]
        seed: Option<u64>,
        /// Write the flight report (JSON) to FILE: the fly report plus, over the hover window
        /// (true state against the set point), alt_rms_m, alt_max_err_m, pos_max_err_m
        /// (largest 3-D distance), roll_rms_rad and pitch_rms_rad.
        #[arg(long, value_name = "FILE")]
        report: Option<PathBuf>,
        /// Folder under which the run folder is created (default: log.dir of the profile).
        #[arg(long, value_name = "DIR")]
        log_dir: Option<PathBuf>,
        /// Inject a fault at T simulated seconds (repeatable): imu-stall (frames stop),
        /// esc-nack (every I2C write fails), gps-loss (fixes stop), log-stall (the x_hat
        /// logger blocks for 500 ms), thrust-loss (motor m0 loses 30 % of its thrust). With
        /// --realtime: imu-stall and esc-nack.
        #[arg(long, value_name = "FAULT@T", value_parser = uquad::sim::faults::parse_injection)]
        inject: Vec<(uquad::sim::faults::Fault, f64)>,
    },
    /// Plot a run's altitude, attitude and motor speeds over time (SVG).
    Plot {
        /// A run folder: ours (logs/<run-id>) or the original's (x_hat.log, w.log).
        run_dir: PathBuf,
        /// Output file (.svg; default RUN_DIR/plot.svg).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
    /// Attach to a running fly or sim: live events, statistics, manual commands.
    #[command(
        long_about = "Attach to a running `uquad fly` or `uquad sim --realtime` through its console \
socket (console.socket of its configuration). Prints the live events (filtered) and a statistics \
line every second (latency histogram, deadline misses, log drops, the estimate and the motor \
speeds). Type a manual-mode key and RET to send it (spec 5.2): j/g roll, y/h pitch, q/w yaw, \
e/d altitude, i/k mass, 0 reset mass, quit; 'filter LEVEL[,TEXT]' changes the filter. Several \
consoles can attach at once; one that stops reading only loses its own events."
    )]
    Console {
        /// The console socket (default: console.socket of config/uquad.toml).
        #[arg(long, value_name = "PATH")]
        socket: Option<PathBuf>,
        /// Event filter: a level (error, warn, info, debug, trace) and optional text, e.g.
        /// "debug,esc".
        #[arg(long, value_name = "FILTER")]
        filter: Option<String>,
    },
    /// Print the fixes gpsd gives, one JSON object per line: a check to run before flying.
    #[command(
        long_about = "Print the fixes gpsd gives, one JSON object per line on stdout: mode (2 or 3), \
lat_deg, lon_deg, alt_m, and x_m, y_m, z_m in the local frame (north, west, up from the first \
fix), plus gpsd's time. Reports without a fix are not printed; logs go to stderr. Exits 0 after \
COUNT fixes, non-zero with the reason when gpsd cannot be reached or goes away."
    )]
    Gps {
        /// gpsd's address.
        #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:2947")]
        gpsd: String,
        /// Fixes to print before exiting.
        #[arg(long, value_name = "N", default_value_t = 10)]
        count: u64,
    },
    /// Design hover gains by LQR from the vehicle model and write them as gain files.
    #[command(
        long_about = "Design hover gains by LQR from the vehicle model (spec 4.5) and write them as gain files.\n\n\
The 12-state model is linearised at hover (w = w_hover(vehicle.mass_kg) on all motors), extended \
with four integrators, discretised at 10 ms and the discrete Riccati equation solved to a relative \
residual below 1e-9, with the weights of control.lqr_q_file (16 x 16) and control.lqr_r_file \
(4 x 4). Writes OUT/K_prop.txt (4 x 12) and OUT/K_int.txt (4 x 4), rows = motors, in the \
convention w = w_hover + K·e + K_int·x_int, and prints the closed-loop spectral radius.\n\n\
Integrating psi and phi cannot work at hover (velocity - g·∫angle is conserved): that design is \
refused with an explanation and nothing is written."
    )]
    Lqr {
        /// Configuration profile (default: config/uquad.toml under the working directory).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        #[command(flatten)]
        sets: SetArgs,
        /// Integrated states: psi,phi,z,theta or x,y,z,theta.
        #[arg(long, value_name = "LIST", default_value = "psi,phi,z,theta")]
        integrators: String,
        /// Folder for K_prop.txt and K_int.txt (created if missing).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
    /// Rerun a recorded flight through the measurement path and write its logs.
    #[command(
        long_about = "Rerun a recorded flight through the core and write its logs.\n\n\
RUN_DIR is a run folder as the original program wrote it: imu_raw.log (required) and, when \
present, kalman_in.log, whose time columns are that run's recorded clock. The replay writes \
OUT_DIR/kalman_in.log in the original's format (OUT_DIR is created if missing; logs in it are \
overwritten). Without --config, RUN_DIR/config.toml is used."
    )]
    Replay {
        /// The run folder to replay (e.g. tests/data/flight-2012-05-25).
        run_dir: PathBuf,
        /// Configuration profile (default: RUN_DIR/config.toml).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        #[command(flatten)]
        sets: SetArgs,
        /// Folder for the output logs.
        #[arg(long, value_name = "OUT_DIR")]
        out: PathBuf,
    },
}

#[derive(clap::Args, Debug)]
struct SetArgs {
    /// Override a configuration key: dotted key, TOML value (e.g. vehicle.mass_kg=1.6,
    /// gps.mode=off). Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = config::parse_set)]
    sets: Vec<(String, toml::Value)>,
}

/// Logs to stderr, filtered by RUST_LOG: compact and coloured on a terminal; under systemd
/// (JOURNAL_STREAM set) no colours and no timestamps, which the journal adds itself. Every
/// event also reaches the attached consoles.
fn init_tracing() {
    use std::io::IsTerminal;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let journal = std::env::var_os("JOURNAL_STREAM").is_some();
    let terminal = std::io::stderr().is_terminal();
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(terminal && !journal);
    let registry = tracing_subscriber::registry()
        .with(filter)
        .with(uquad::console::ConsoleLayer);
    if journal {
        registry.with(fmt.without_time()).init();
    } else if terminal {
        registry.with(fmt.compact()).init();
    } else {
        registry.with(fmt).init();
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_tracing();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn load_profile(path: &std::path::Path, sets: &SetArgs) -> anyhow::Result<config::Profile> {
    config::load(path, &sets.sets).map_err(|e| anyhow::anyhow!("invalid configuration:\n{e}"))
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::CheckConfig { file, sets } => match config::load(&file, &sets.sets) {
            Ok(profile) => {
                println!("{}: valid", profile.path.display());
                Ok(ExitCode::SUCCESS)
            }
            Err(e) => {
                for p in &e.problems {
                    eprintln!("{p}");
                }
                eprintln!("{} problem(s) found", e.problems.len());
                Ok(ExitCode::FAILURE)
            }
        },
        Command::Fly {
            config,
            sets,
            log_dir,
            report,
        } => {
            let path = config::resolve_path(config.as_deref()).map_err(anyhow::Error::msg)?;
            let profile = load_profile(&path, &sets)?;
            let cfg = &profile.config;
            let rt = tokio::runtime::Runtime::new().context("cannot start the runtime")?;
            let summary = rt.block_on(async {
                let imu = uquad::hw::serial::open_imu(&cfg.imu.device, cfg.imu.baud)?;
                let bus = uquad::hw::esc_bus::LinuxEscBus::open(&cfg.esc.bus, &cfg.esc.addresses)?;
                uquad::app::fly::run(
                    &profile,
                    uquad::app::fly::Edges {
                        imu: Box::new(imu),
                        bus: Box::new(bus),
                        gps_fixes: None,
                        live: None,
                    },
                    uquad::app::fly::FlyOptions {
                        log_dir,
                        realtime: true,
                        stdin_keys: true,
                        log_stall: None,
                        handle_signals: true,
                        control_delay: None,
                    },
                    tokio_util::sync::CancellationToken::new(),
                )
                .await
            });
            // A blocked stdin read must not hold the process after the run.
            rt.shutdown_timeout(std::time::Duration::from_millis(200));
            let summary = summary?;
            eprintln!("{}", summary.text());
            if let Some(path) = report {
                summary.write_report(&path)?;
            }
            Ok(if summary.error.is_some() || summary.halt.is_some() {
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            })
        }
        Command::Sim {
            config,
            sets,
            duration,
            realtime,
            fast: _,
            seed,
            report,
            log_dir,
            inject,
        } => {
            let path = config::resolve_path(config.as_deref()).map_err(anyhow::Error::msg)?;
            let profile = load_profile(&path, &sets)?;
            use uquad::sim::faults::Fault;
            if realtime
                && let Some((f, _)) = inject
                    .iter()
                    .find(|(f, _)| !matches!(f, Fault::ImuStall | Fault::EscNack))
            {
                anyhow::bail!(
                    "--inject {}: with --realtime only imu-stall and esc-nack can be injected",
                    f.name()
                );
            }
            let opts = uquad::app::sim::SimOptions {
                inject,
                duration_s: duration,
                seed,
                log_dir,
                progress: true,
            };
            let summary = if realtime {
                let rt = tokio::runtime::Runtime::new().context("cannot start the runtime")?;
                let s = rt.block_on(uquad::app::sim_realtime::run(&profile, &opts));
                rt.shutdown_timeout(std::time::Duration::from_millis(200));
                s?
            } else {
                uquad::app::sim_fast::run_fast(&profile, &opts)?
            };
            eprintln!("{}", summary.text());
            if let Some(path) = report {
                uquad::app::report::write_json(&summary.report(), &path)?;
            }
            Ok(
                if summary.fly.error.is_some() || summary.fly.halt.is_some() {
                    ExitCode::FAILURE
                } else {
                    ExitCode::SUCCESS
                },
            )
        }
        Command::Console { socket, filter } => {
            let path = match socket {
                Some(p) => p,
                None => {
                    let cfg = config::resolve_path(None).map_err(anyhow::Error::msg)?;
                    load_profile(&cfg, &SetArgs { sets: vec![] })?
                        .config
                        .console
                        .socket
                }
            };
            let rt = tokio::runtime::Runtime::new().context("cannot start the runtime")?;
            let r = rt.block_on(uquad::console::attach(&path, filter.as_deref()));
            rt.shutdown_timeout(std::time::Duration::from_millis(100));
            r?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Plot { run_dir, out } => {
            let path = uquad::app::plot::run(&run_dir, out.as_deref())?;
            println!("{}", path.display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Gps { gpsd, count } => {
            let rt = tokio::runtime::Runtime::new().context("cannot start the runtime")?;
            rt.block_on(uquad::app::gps::run(
                &gpsd,
                count,
                &mut std::io::stdout().lock(),
            ))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Lqr {
            config,
            sets,
            integrators,
            out,
        } => {
            let set = uquad::core::control::Integrators::parse(&integrators)
                .filter(|s| *s != uquad::core::control::Integrators::ZTheta)
                .with_context(|| {
                    format!(
                        "--integrators {integrators:?}: expected psi,phi,z,theta or x,y,z,theta"
                    )
                })?;
            let path = config::resolve_path(config.as_deref()).map_err(anyhow::Error::msg)?;
            let profile = load_profile(&path, &sets)?;
            let outcome = uquad::app::lqr::run(&profile, set, &out)?;
            println!(
                "closed-loop spectral radius {:.9} (relative Riccati residual {:.2e})",
                outcome.design.spectral_radius, outcome.design.residual_rel
            );
            println!("{}", outcome.k_prop_path.display());
            println!("{}", outcome.k_int_path.display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Replay {
            run_dir,
            config,
            sets,
            out,
        } => {
            let path = match config {
                Some(p) => p,
                None => {
                    let p = run_dir.join("config.toml");
                    if !p.is_file() {
                        anyhow::bail!(
                            "{} has no config.toml; pass --config FILE (config/flight-2012-05.toml for the 2012 runs)",
                            run_dir.display()
                        );
                    }
                    p
                }
            };
            let profile = load_profile(&path, &sets)?;
            let summary = uquad::app::replay::run(&run_dir, &profile, &out)
                .with_context(|| format!("replay of {} failed", run_dir.display()))?;
            tracing::info!(
                raw_frames = summary.raw_frames,
                kalman_steps = summary.kalman_steps,
                gps_updates = summary.gps_updates,
                dt_clamped = summary.dt_clamped,
                ekf_errors = summary.ekf_errors,
                "replay finished"
            );
            for o in &summary.outputs {
                println!("{}", o.display());
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
