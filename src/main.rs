//! The `uquad` command: parses the command line (one argument struct per command, each with
//! its `run`), sets up tracing, loads the profile and hands over to the modes in `uquad::app`.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;
use uquad::app::report::{FlySummary, write_json};
use uquad::app::sim::{SimMode, SimOptions};
use uquad::config::{self, Profile};
use uquad::sim::faults::{Fault, parse_injection};

#[derive(Parser, Debug)]
#[command(
    name = "uquad",
    version,
    about = "Flight software for the uQuad quadcopter",
    long_about = "Flight software for the uQuad quadcopter: IMU measurement path, the original's 15-state EKF (gyro-bias and receiver-bias states added), \
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
(or the position of a malformed number in a data file) and the problem, and exits 2."
    )]
    CheckConfig(CheckConfigArgs),
    /// Fly: the flight program (serial IMU, EKF, controller, ESCs over I2C, loggers).
    #[command(long_about = "Fly: the flight program the BeagleBoard runs.\n\n\
Opens the IMU on imu.device (115200 8N1 raw) and the ESCs on esc.bus (Linux I2C). Start-up: \
wait for a stable IMU sampling period (motors off), calibrate the IMU at rest (512 frames) and \
run the estimator, disarmed; on `arm` (once the estimator check passes) run the ESC start-up \
ramp; on `takeoff` ramp the motors up over 100 steps, then hover at control.hover_z_m \
(imu.calibrate = \"after-arm\", or commander.start = \"flying\": the ESC ramp, then the \
calibration with the motors idling, as the original did). \
Logs go to <log dir>/<run-id>/ (imu_raw, kalman_in, x_hat, innov, w, int, setpoint, gps, err, \
mode, and the resolved \
config.toml with copies of its data files, so `uquad replay <run folder>` reruns it).\n\n\
SIGINT, SIGTERM, SIGHUP and SIGQUIT zero and disable the motors, then the report and logs are \
written; a second signal is noted, a third exits once the motors are stopped. SIGTSTP is ignored \
(a suspended flight could not stop its motors). The original's manual-mode keys work from stdin (j/g roll, y/h pitch, q/w yaw, e/d \
altitude, i/k mass, 0 reset mass, ESC quit).")]
    Fly(FlyArgs),
    /// Simulate: fly the real code against a physics model of the uQuad (the main job).
    #[command(
        long_about = "Simulate: fly the real code against a physics model of the uQuad.\n\n\
The simulated IMU sends real 30-byte frames (raw counts from the true state through the \
inverted calibration, with noise), the simulated ESCs take the real I2C register writes, and \
the flight goes through settle, IMU calibration at rest, arm, ESC start-up ramp, flight ramp \
and hover, as \
`fly` does. With gps.mode = \"gpsd\" (the default profile) a fix of the true position reaches \
the filter each simulated second, where `fly` would read gpsd. The run folder logs/<run-id>/ is written as `fly` writes it, so \
`uquad replay <run folder> --out DIR` reruns it to identical bytes.\n\n\
--mode fast (the default; also --fast) runs the flight's state machines in lock-step with the \
physics on a simulated clock: 40 simulated seconds take well under a second. --mode realtime \
(also --realtime) runs fly's own tasks and threads against the simulated edges, paced by the \
wall clock. --mode paced runs the lock-step flight of --fast paced to the wall clock (--speed \
FACTOR simulated seconds per second), with the ground-station link and the console served and \
the logs written as the run goes: the watchdog judges simulated time, so a busy host slows the \
flight instead of halting it (for practising with a ground station; --realtime stays the test \
of the real threads). All follow the same flight sequence and report the hover window the same \
way: from sim.settle_s after the flight ramp, against the set point.\n\n\
With no arguments: config/uquad.toml and its operator's cycle (--script: arm at 7 s, once the \
estimator check passes, take off at 10 s to 1 m, land at 45 s); the run ends once the vehicle has landed and disarmed, at most \
sim.duration_s; a summary at the end.\n\n\
In --realtime and --mode paced a ground station can watch and fly it over MAVLink 2 (gcs.*): \
telemetry goes to UDP 127.0.0.1:14550, where QGroundControl and MAVProxy listen."
    )]
    Sim(SimArgs),
    /// The safety campaign: every simulated fault in every phase, alone and in pairs, judged.
    #[command(
        long_about = "The safety campaign: `sim --fast` runs of every simulated fault struck in \
every phase of a flight, alone and in pairs, each with its own seed, on every core.\n\n\
The phases are windows of simulated time in three scripted flights, fitted to the default \
profile's start-up: calibration (at rest), disarmed, esc-ramp, armed-ground, takeoff, hold and \
landing \
(\"arm@7,takeoff@10,land@45\"), mission-leg (--mission, \"arm@7,start@10\") and return \
(\"arm@7,takeoff@10,hold 6 0 1@14,return@24\"); each run draws its strike times within the \
phase from its seed. The runs take the cases in turn (9 phases x (12 faults + 66 pairs) = 702), \
so --runs 1000 flies each once or twice.\n\n\
Each run is judged against seven invariants: (1) every ESC's last writes are zero then \
disable, or it is named unconfirmed; (2) no run ends armed, and the motors never idle on the \
ground past commander.disarm_ground_s + 1 s; (3) every contact with the ground before a halt at \
most 1 m/s, and at most commander.land_slow_m_s + 0.25 m/s when the faults left a position; \
(4) a halt in the air only for the watchdog's causes, kill or crash, and `estimator` only when \
a fault took the attitude (the simulator lets the vehicle fall after it and reports the impact \
speed); (5) the true vehicle within fence.radius_m + 10 m; (6) a lost link, lost fixes or a \
silent IMU acted on within its configured time, and a gps-loss's landing within \
failsafe.gps_loss_land_s; (7) the report's modes, failsafes, halt and \
refusal count are mode.log's.\n\n\
Prints a table of outcomes (a row per fault, a column per phase, the most common outcome), \
each violation with the `uquad sim` command line that reruns it, and the known exceptions \
apart (a gyro the filter cannot follow: stuck, its landing flown on the model's attitude, or its bias stepped; breaking 3 or 5). Exits 1 when an \
invariant was violated."
    )]
    Campaign(CampaignArgs),
    /// Plot a run: altitude, attitude, motor speeds, its track, modes (PNG or SVG).
    #[command(
        long_about = "Plot a run folder (ours, or the original's x_hat.log and w.log): altitude, \
roll and pitch, yaw and the motor speeds over time, each estimate with its set point (dashed), \
and the horizontal track flown against the planned one, east and north on one scale. Mode \
changes (grey) and failsafes (red) are marked on every panel. The format follows the output's \
extension: .png (default RUN_DIR/plot.png; text in the embedded DejaVu Sans, the same on every \
machine) or .svg."
    )]
    Plot(PlotArgs),
    /// Each sensor's noise from a still segment of a run: Allan deviation, the filter's R.
    #[command(
        long_about = "Each sensor's noise from a still segment of a run's imu_raw.log (the vehicle \
at rest: a calibration, or a simulated vehicle on the ground). The frames are converted with the \
run's imu_calib.txt (or --calib) as the estimator converts them. For each gyro and accelerometer \
axis: the mean, the standard deviation, and the terms of the Allan deviation fitted by IEEE Std \
952's model — the white noise per frame and its density (unit·√s), the bias instability and the \
bias random walk (unit/√s); the standard deviation of the barometer's altitude and pressure and \
of the angles the IMU derives (roll, pitch from the accelerometer, yaw from the magnetometer). \
Then the ekf.r_imu diagonal those imply and the accelerometer biases' process noise per step. \
Minutes of stillness are needed for the slow terms; a short or moving segment is warned about. \
Example (the 2012 flight's calibration, motors idling): uquad noise \
tests/data/flight-2012-05-25 --calib config/imu_calib.txt --to 12.12"
    )]
    Noise(NoiseArgs),
    /// Export a run for Flight Review, PlotJuggler, pyulog (ULog) or spreadsheets (CSV).
    #[command(
        long_about = "Export a run folder (ours, or the original's) for the tools people use. \
--format ulog writes one ULog file (PX4's log format) with PX4's topic and field names: \
vehicle_attitude, vehicle_local_position, vehicle_local_position_setpoint, \
vehicle_attitude_setpoint, actuator_outputs (motor speeds, rad/s), sensor_combined, \
vehicle_air_data, vehicle_gps_position, estimator_status (the innovation test ratios), \
vehicle_status (modes and failsafes), uquad_imu_raw (the IMU frames in counts), north-east-down; the run's configuration as parameters \
(the ids `uquad params` lists); mode.log's events and err.log's lines as logged messages. \
--format csv writes a folder with one file per stream, each column's unit in its header. \
The logs are read a line at a time, so memory does not grow with the run's length (a 1.2 GB \
run folder exports at under 10 MB); a line over 64 KiB, a last line cut off or a line not \
understood is skipped and named on stderr. The files are written as .partial and take their \
names once the export has succeeded: a failed export leaves an earlier one as it was."
    )]
    Export(ExportArgs),
    /// Attach to a running fly or sim: live events, statistics, manual commands.
    #[command(
        long_about = "Attach to a running `uquad fly` or `uquad sim --realtime` through its console \
socket (console.socket of its configuration). Prints the live events (filtered) and a statistics \
line every second (latency histogram and its stages, deadline misses, log drops, the estimate and the motor \
speeds). Type a manual-mode key and RET to send it (spec 5.2): j/g roll, y/h pitch, q/w yaw, \
e/d altitude, i/k mass, 0 reset mass, quit; 'filter LEVEL[,TEXT]' changes the filter. Several \
consoles can attach at once; one that stops reading only loses its own events."
    )]
    Console(ConsoleArgs),
    /// List the parameters a ground station sees: MAVLink id, key, value.
    #[command(
        long_about = "List the parameters a ground station sees over MAVLink: one line each with \
its id (at most 16 characters), the configuration key it stands for, its value in this profile \
(with the parameters kept from earlier runs applied, as `fly` and `sim` apply them), whether \
it is flight-critical (a ground station's change is refused while armed) and when a change takes \
effect: `flight` (the running flight's next step: the commander's speeds and heights, the \
failsafes' timeouts; recorded in mode.log, so a replay applies it at the same step) or `start` \
(the next run).\n\n\
The profile's numbers and true/false keys are parameters; text keys and lists are not."
    )]
    Params(ParamsArgs),
    /// Print the fixes gpsd gives, one JSON object per line: a check to run before flying.
    #[command(
        long_about = "Print the fixes gpsd gives, one JSON object per line on stdout: mode (2 or 3), \
lat_deg, lon_deg, alt_m, and x_m, y_m, z_m in the local frame (north, west, up from the first \
fix), plus gpsd's time. Reports without a fix are not printed; logs go to stderr. Exits 0 after \
COUNT fixes, non-zero with the reason when gpsd cannot be reached or goes away."
    )]
    Gps(GpsArgs),
    /// Design gains by LQR at hover or along a path; print them or write them as gain files.
    #[command(
        long_about = "Design gains by LQR from the vehicle model (spec 4.5), at hover or about a path's trim.\n\n\
The 12-state model is linearised about the trim (hover: w = w_hover(vehicle.mass_kg) on all \
motors; --path straight: level flight at --speed; --path circle: a coordinated turn of --radius \
at --speed, the heading turning with the path, modelled in the frame that turns with it), \
extended with four integrators, discretised at 10 ms and the discrete Riccati equation solved to \
a relative residual below 1e-9, with the weights of control.lqr_q_file (16 x 16) and \
control.lqr_r_file (4 x 4). Prints the trim (attitude, body velocity and rates, motor speeds), \
the closed-loop spectral radius and the residual, then the gains; with --out writes \
OUT/K_prop.txt (4 x 12) and OUT/K_int.txt (4 x 4) instead, rows = motors, in the convention \
w = w_trim + K·e + K_int·x_int.\n\n\
Examples:\n  uquad lqr --out /tmp/hover\n  uquad lqr --path straight --speed 1\n  \
uquad lqr --path circle --radius 5 --speed 1 --turn right\n\n\
Integrating psi and phi cannot work at hover (velocity - g·∫angle is conserved): that design is \
refused with an explanation and nothing is written."
    )]
    Lqr(LqrArgs),
    /// Rerun a recorded flight through the measurement path and write its logs.
    #[command(
        long_about = "Rerun a recorded flight through the core and write its logs.\n\n\
RUN_DIR is a run folder as the original program wrote it: imu_raw.log (required) and, when \
present, kalman_in.log, whose time columns are that run's recorded clock. The replay writes \
OUT_DIR/kalman_in.log, x_hat.log, w.log and int.log in the original's formats, innov.log \
(the EKF's innovation test ratios per step), setpoint.log and mode.log (OUT_DIR is created if \
missing; logs in it are overwritten). Without --config, RUN_DIR/config.toml is used.\n\n\
Several RUN_DIRs are replayed at once, spread over every core, each into OUT_DIR/<its folder's \
name> (a repeated name gets -2, -3, ...); a progress bar on a terminal, then one line: runs, \
Kalman steps, time and steps per second. A run that fails is named with its reason on stderr, \
the others are still written, and the exit status is non-zero."
    )]
    Replay(ReplayArgs),
    /// Write the book's reference pages from the code: commands, configuration keys, MAVLink.
    #[command(
        long_about = "Write the book's reference pages from the code itself: every command's \
--help (commands.md), every configuration key with its built-in value, what its checks allow and \
its MAVLink parameter id (config.md), and every MAVLink message and command the link handles \
(mavlink.md).\n\n\
Run it after changing a command, a key or the link, and commit the pages: the tests fail while a \
page in docs/src/reference differs from what this writes."
    )]
    Reference(ReferenceArgs),
}

#[derive(clap::Args, Debug)]
struct CheckConfigArgs {
    /// The configuration file (TOML), e.g. config/uquad.toml.
    file: PathBuf,
    #[command(flatten)]
    sets: SetArgs,
}

#[derive(clap::Args, Debug)]
struct FlyArgs {
    #[command(flatten)]
    profile: ProfileArgs,
    /// Folder under which the run folder is created (default: log.dir of the profile).
    #[arg(long, value_name = "DIR")]
    log_dir: Option<PathBuf>,
    /// Write the flight report (JSON: frames, steps, latency_us {p50, p99, max},
    /// latency_stages_us {decode_to_estimate, estimate_to_command, command_to_write},
    /// deadline_misses, log_drops, watchdog_trips, halt, run_dir) to FILE at the end.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Fly even when SCHED_FIFO or locked memory is refused (a bench test as an ordinary
    /// user): without them nothing bounds the control path's latency, and the 2 ms between
    /// the 10 ms frame period and the 12 ms IMU timeout can be lost to any other process.
    #[arg(long)]
    allow_no_rt: bool,
    /// Arm once it can - the IMU settled and, calibrated at rest (imu.calibrate =
    /// "before-arm"), the estimator check passing - as if `arm` were typed (the pre-arm checks
    /// still apply; a refusal is logged and the vehicle stays disarmed). Then `takeoff` from
    /// stdin or a console. Profiles with commander.start = "flying" arm and take off by themselves.
    #[arg(long)]
    arm: bool,
    /// Load the mission in FILE (e.g. config/missions/square.toml); `start` flies it (from
    /// the ground: its takeoff first), `pause`, `resume` and `return` steer it.
    #[arg(long, value_name = "FILE")]
    mission: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct SimArgs {
    #[command(flatten)]
    profile: ProfileArgs,
    /// Simulated seconds, start-up included: more than 0, at most 86400 (default:
    /// sim.duration_s).
    #[arg(
        long,
        value_name = "S",
        value_parser = config::parse_duration_s,
        allow_negative_numbers = true
    )]
    duration: Option<f64>,
    /// fast: the flight's state machines in lock-step with the physics on a simulated clock
    /// (the default); realtime: fly's own tasks and threads on the wall clock; paced: the
    /// lock-step flight paced to the wall clock, a ground station and the console served.
    #[arg(long, value_enum, value_name = "MODE", conflicts_with_all = ["fast", "realtime"])]
    mode: Option<SimMode>,
    /// --mode paced: simulated seconds per wall second, 0.1 to 100 (default 1;
    /// ArduPilot's SITL speed-up). The link-loss failsafe's timeout is scaled by it, so that
    /// it stays the ground station's wall-clock timeout.
    #[arg(long, value_name = "FACTOR", value_parser = parse_speed)]
    speed: Option<f64>,
    /// Same as --mode realtime.
    #[arg(long, conflicts_with = "fast")]
    realtime: bool,
    /// Same as --mode fast.
    #[arg(long)]
    fast: bool,
    /// Fly with the pilot's radio: a simulated transmitter sends SBUS or CRSF frames, moved
    /// by the script's `sticks R P Y T`, `switch arm|kill on|off` and `switch mode NAME`
    /// (the same as --set rc.protocol="sbus" or "crsf"; `--inject rc-loss@T` loses it).
    #[arg(long, value_name = "PROTOCOL", value_parser = ["sbus", "crsf"])]
    rc: Option<String>,
    /// Seed of every random draw, 0 to 2^63 − 1 (default: sim.seed).
    #[arg(
        long,
        value_name = "N",
        value_parser = config::parse_seed,
        allow_negative_numbers = true
    )]
    seed: Option<u64>,
    /// Write the flight report (JSON) to FILE: the fly report plus, over the hover window
    /// (true state against the set point), alt_rms_m, alt_max_err_m, pos_max_err_m
    /// (largest 3-D distance), roll_rms_rad and pitch_rms_rad.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Folder under which the run folder is created (default: log.dir of the profile).
    #[arg(long, value_name = "DIR")]
    log_dir: Option<PathBuf>,
    /// Inject a fault at T simulated seconds, 0 to 86400 (repeatable): imu-stall (frames stop),
    /// esc-nack (every I2C write fails), gps-loss (fixes stop), log-stall (the x_hat
    /// logger blocks for 500 ms), thrust-loss (motor m0 loses 30 % of its thrust), baro-fail,
    /// gyro-stuck, imu-garbage, link-loss (the simulated operator's heartbeats and commands
    /// stop), gust (a push north of sim.gust_n for sim.gust_s), gps-glitch, gyro-bias,
    /// rc-loss (with --rc: the receiver's failsafe flag, SBUS, or its silence, CRSF).
    #[arg(long, value_name = "FAULT@T", value_parser = parse_injection)]
    inject: Vec<(Fault, f64)>,
    /// The simulated operator's commands at simulated seconds, e.g. "arm@7,takeoff 1.5@10,
    /// land@45" (arm, takeoff [ALT_M], hold [X Y Z], land, disarm, kill, motor M PCT S; with
    /// --rc the pilot's radio too: sticks R P Y T, switch arm|kill on|off, switch mode NAME;
    /// a landed vehicle
    /// may be armed again: several flights per run); the run ends once the vehicle is
    /// disarmed after them. "none": no operator (use the console or a ground station); the
    /// run goes on after each landing until --duration or a signal. The
    /// operator also sends a ground station's link heartbeats each second. Default: the whole
    /// cycle, "arm@7,takeoff@10,land@45" (none when commander.start = "flying"): the default
    /// profile calibrates at rest and its estimator check passes by 6.2 s.
    #[arg(long, value_name = "SCRIPT", value_parser = uquad::sim::operator::Script::parse)]
    script: Option<uquad::sim::operator::Script>,
    /// Fly the mission in FILE (e.g. config/missions/square.toml): the default script becomes
    /// "arm@7,start@10" and the run ends at the mission's touchdown; the report gains
    /// track_rms_m, track_max_m, mission_s and mission_ideal_s.
    #[arg(long, value_name = "FILE")]
    mission: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct CampaignArgs {
    #[command(flatten)]
    profile: ProfileArgs,
    /// Runs, 1 to 1000000.
    #[arg(long, value_name = "N", default_value_t = 1000,
          value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    runs: u64,
    /// The campaign's seed: run i flies with seed S + i.
    #[arg(long, value_name = "S", default_value_t = 1,
          value_parser = clap::value_parser!(u64).range(0..=(i64::MAX as u64) / 2))]
    seed: u64,
    /// Runs at once (default: the machine's cores).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=256))]
    jobs: Option<u64>,
    /// The mission the mission-leg phase flies (default: missions/square.toml beside the
    /// profile).
    #[arg(long, value_name = "FILE")]
    mission: Option<PathBuf>,
    /// Write the campaign's report (JSON): runs, violations (invariant, run, seen),
    /// known_exceptions, outcomes, worst_fall, wall_s, runs_per_s.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct ExportArgs {
    /// A run folder: ours (logs/<run-id>) or the original's (x_hat.log, w.log).
    run_dir: PathBuf,
    /// ulog: one file; csv: a folder of files, one per stream.
    #[arg(long, value_enum)]
    format: uquad::app::export::Format,
    /// The file (ulog, e.g. run.ulg) or folder (csv) to write.
    #[arg(long, value_name = "PATH")]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct NoiseArgs {
    /// A run folder with imu_raw.log (ours, or the original's).
    run_dir: PathBuf,
    /// The segment's start, s in the log's first column (t_main); default its first frame.
    #[arg(long, value_name = "S")]
    from: Option<f64>,
    /// The segment's end, s; default the log's last frame.
    #[arg(long, value_name = "S")]
    to: Option<f64>,
    /// The calibration to convert the frames with (default RUN_DIR/imu_calib.txt).
    #[arg(long, value_name = "FILE")]
    calib: Option<PathBuf>,
    /// Also write the figures as JSON, each axis with its Allan curve.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct PlotArgs {
    /// A run folder: ours (logs/<run-id>) or the original's (x_hat.log, w.log).
    run_dir: PathBuf,
    /// Output file, .png or .svg (default RUN_DIR/plot.png).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct ConsoleArgs {
    /// The console socket (default: console.socket of config/uquad.toml).
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Event filter: a level (error, warn, info, debug, trace) and optional text, e.g.
    /// "debug,esc".
    #[arg(long, value_name = "FILTER")]
    filter: Option<String>,
}

#[derive(clap::Args, Debug)]
struct ParamsArgs {
    #[command(flatten)]
    profile: ProfileArgs,
    /// The log folder whose params.toml holds the kept parameters (default: log.dir).
    #[arg(long, value_name = "DIR")]
    log_dir: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct ReferenceArgs {
    /// The folder the pages go into (created if missing).
    #[arg(long, value_name = "DIR", default_value = "docs/src/reference")]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct GpsArgs {
    /// gpsd's address.
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:2947")]
    gpsd: String,
    /// Fixes to print before exiting.
    #[arg(long, value_name = "N", default_value_t = 10)]
    count: u64,
}

#[derive(clap::Args, Debug)]
struct LqrArgs {
    #[command(flatten)]
    profile: ProfileArgs,
    /// Integrated states: psi,phi,z,theta or x,y,z,theta (default: the profile's
    /// control.integrators).
    #[arg(long, value_name = "LIST")]
    integrators: Option<String>,
    /// The trim the design is about.
    #[arg(long, value_enum, default_value = "hover")]
    path: LqrPath,
    /// Speed along the path, m/s (straight and circle).
    #[arg(long, value_name = "M_S")]
    speed: Option<f64>,
    /// The circle's radius, m.
    #[arg(long, value_name = "M")]
    radius: Option<f64>,
    /// The circle's direction seen from above: left (counter-clockwise) or right.
    #[arg(long, value_enum, default_value = "left")]
    turn: Turn,
    /// Direction of travel relative to the nose, degrees (0: nose first; 90: to the left).
    #[arg(
        long,
        value_name = "DEG",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    course_deg: f64,
    /// Folder for K_prop.txt and K_int.txt (created if missing); without it the gains are
    /// printed.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum LqrPath {
    Hover,
    Straight,
    Circle,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Turn {
    Left,
    Right,
}

#[derive(clap::Args, Debug)]
struct ReplayArgs {
    /// The run folder to replay (e.g. tests/data/flight-2012-05-25); several: each into
    /// OUT_DIR/<its name>, on every core.
    #[arg(required = true, num_args = 1.., value_name = "RUN_DIR")]
    run_dirs: Vec<PathBuf>,
    /// Configuration profile (default: RUN_DIR/config.toml).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    #[command(flatten)]
    sets: SetArgs,
    /// Folder for the output logs.
    #[arg(long, value_name = "OUT_DIR")]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct SetArgs {
    /// Override a configuration key: dotted key, TOML value (e.g. vehicle.mass_kg=1.6,
    /// gps.mode=off). Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = config::parse_set)]
    sets: Vec<(String, toml::Value)>,
}

impl SetArgs {
    /// Loads and validates the profile at `path` with these overrides.
    fn load(&self, path: &Path) -> anyhow::Result<Profile> {
        config::load(path, &self.sets)
            .map_err(|e| Refused(format!("invalid configuration:\n{e}")).into())
    }
}

/// A refused configuration or command line, as opposed to a run that failed: it exits with
/// `REFUSED_EXIT`, the status clap gives a bad argument, so a script can tell the two apart.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct Refused(String);

/// Exit status of a refused configuration or command line.
const REFUSED_EXIT: u8 = 2;

/// The profile arguments of the commands that fly or design: `--config` and `--set`.
#[derive(clap::Args, Debug)]
struct ProfileArgs {
    /// Configuration profile (default: config/uquad.toml under the working directory).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    #[command(flatten)]
    sets: SetArgs,
}

impl ProfileArgs {
    fn load(&self) -> anyhow::Result<Profile> {
        let path = config::resolve_path(self.config.as_deref()).map_err(Refused)?;
        self.sets.load(&path)
    }

    /// The profile with the parameters a ground station kept from earlier runs (`fly`,
    /// `sim`): the log folder is `log_dir` when the command line gives one.
    fn load_kept(&self, log_dir: Option<&Path>) -> anyhow::Result<Profile> {
        let path = config::resolve_path(self.config.as_deref()).map_err(Refused)?;
        let (profile, kept) = config::load_kept(&path, &self.sets.sets, log_dir)
            .map_err(|e| Refused(format!("invalid configuration:\n{e}")))?;
        if let Some((file, n)) = kept {
            tracing::info!("{n} parameter(s) kept from {}", file.display());
        }
        Ok(profile)
    }
}

/// Logs to stderr, filtered by RUST_LOG: compact and coloured on a terminal; under systemd
/// (JOURNAL_STREAM set) no colours and no timestamps, which the journal adds itself. Every
/// event also reaches the attached consoles.
fn init_tracing() -> tracing_appender::non_blocking::WorkerGuard {
    use std::io::IsTerminal;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    // Events reach stderr through a queue and a thread of their own: a stalled terminal (a
    // paused ssh session, a full pipe) must never stall the thread that logs — the control
    // path, the ESC writer. What the queue cannot hold is dropped and counted. 4096 lines hold
    // any burst a run makes; the crate's default of 128 000 made every command start by
    // touching 4 MB (a sixth of a whole replay's time).
    let (stderr, guard) = tracing_appender::non_blocking::NonBlockingBuilder::default()
        .buffered_lines_limit(4096)
        .lossy(true)
        .finish(std::io::stderr());
    uquad::console::count_stderr_drops(stderr.error_counter());
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let journal = std::env::var_os("JOURNAL_STREAM").is_some();
    let terminal = std::io::stderr().is_terminal();
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(stderr)
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
    guard
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Held to the end of main: dropping it writes out what is still queued for stderr.
    let _stderr = init_tracing();
    let result = match cli.command {
        Command::CheckConfig(a) => a.run(),
        Command::Fly(a) => a.run(),
        Command::Sim(a) => a.run(),
        Command::Campaign(a) => a.run(),
        Command::Plot(a) => a.run(),
        Command::Noise(a) => a.run(),
        Command::Export(a) => a.run(),
        Command::Console(a) => a.run(),
        Command::Params(a) => a.run(),
        Command::Gps(a) => a.run(),
        Command::Lqr(a) => a.run(),
        Command::Replay(a) => a.run(),
        Command::Reference(a) => a.run(),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.is::<Refused>() {
                ExitCode::from(REFUSED_EXIT)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// The profile with the mission in `path`, if one is given.
fn with_mission(profile: Profile, path: Option<&Path>) -> anyhow::Result<Profile> {
    match path {
        Some(p) => Ok(profile.with_mission(p).map_err(Refused)?),
        None => Ok(profile),
    }
}

/// Runs `work` on a new runtime, then shuts the runtime down without waiting more than
/// `grace` for tasks still blocked on I/O (a stdin read must not hold the process).
fn on_runtime<T>(grace: Duration, work: impl std::future::Future<Output = T>) -> anyhow::Result<T> {
    let rt = tokio::runtime::Runtime::new().context("cannot start the runtime")?;
    let out = rt.block_on(work);
    rt.shutdown_timeout(grace);
    Ok(out)
}

/// A run that could not be made (a log folder that cannot be written, a device that cannot
/// be opened): its error is still the report's `error` when one was asked for (a report on
/// another disk outlives a full log disk), then the run's error.
fn reported_failure<T>(run: anyhow::Result<T>, report: Option<&Path>) -> anyhow::Result<T> {
    let e = match run {
        Ok(v) => return Ok(v),
        Err(e) => e,
    };
    if let Some(path) = report {
        let mut failed = FlySummary::empty(std::path::PathBuf::new());
        failed.error = Some(format!("{e:#}"));
        if let Err(w) = write_json(&failed.report(), path) {
            eprintln!("error: {w:#}");
        }
    }
    Err(e)
}

/// A run that a halt or an error ended fails, once its summary and report are out.
fn exit_code(summary: &FlySummary) -> ExitCode {
    if summary.error.is_some() || summary.halt.is_some() {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

impl CheckConfigArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        match config::load(&self.file, &self.sets.sets) {
            Ok(profile) => {
                println!("{}: valid", profile.path.display());
                Ok(ExitCode::SUCCESS)
            }
            Err(e) => {
                for p in &e.problems {
                    eprintln!("{p}");
                }
                eprintln!("{} problem(s) found", e.problems.len());
                Ok(ExitCode::from(REFUSED_EXIT))
            }
        }
    }
}

impl FlyArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        use uquad::app::fly::{Edges, FlyOptions};
        let profile = self.profile.load_kept(self.log_dir.as_deref())?;
        let profile = with_mission(profile, self.mission.as_deref())?;
        let cfg = &profile.config;
        // Before any device is opened: a flight without real-time guarantees is refused.
        if !self.allow_no_rt
            && let Err(why) = uquad::tasks::realtime_permitted()
        {
            anyhow::bail!(
                "real-time scheduling refused: {why}. Run as the uquad service (its unit sets LimitRTPRIO and LimitMEMLOCK) or as root, or pass --allow-no-rt to fly without it"
            );
        }
        let opts = FlyOptions {
            log_dir: self.log_dir,
            realtime: true,
            stdin_keys: true,
            handle_signals: true,
            arm_at_start: self.arm,
            realtime_waived: self.allow_no_rt,
            gcs: cfg.gcs.enabled == config::GcsEnabled::Always,
            ..FlyOptions::default()
        };
        let summary = on_runtime(Duration::from_millis(200), async {
            let rc = match cfg.rc.protocol {
                config::RcProtocol::None => None,
                p => Some(Box::new(uquad::hw::serial::open_rc(&cfg.rc.device, p)?)
                    as Box<dyn tokio::io::AsyncRead + Send + Unpin>),
            };
            let edges = Edges {
                rc,
                operator: None,
                imu: Box::new(uquad::hw::serial::open_imu(&cfg.imu.device, cfg.imu.baud)?),
                bus: Box::new(uquad::hw::esc_bus::LinuxEscBus::open(
                    &cfg.esc.bus,
                    &cfg.esc.addresses,
                )?),
                gps_fixes: None,
                live: None,
            };
            let cancel = tokio_util::sync::CancellationToken::new();
            uquad::app::fly::run(&profile, edges, opts, cancel).await
        })
        .and_then(|r| r);
        let summary = reported_failure(summary, self.report.as_deref())?;
        eprintln!("{}", summary.text());
        if let Some(path) = self.report {
            summary.write_report(&path)?;
        }
        Ok(exit_code(&summary))
    }
}

impl SimArgs {
    fn mode(&self) -> SimMode {
        match (self.realtime, self.fast) {
            (true, _) => SimMode::Realtime,
            (_, true) => SimMode::Fast,
            _ => self.mode.unwrap_or_default(),
        }
    }

    fn run(mut self) -> anyhow::Result<ExitCode> {
        let mode = self.mode();
        if self.speed.is_some() && mode != SimMode::Paced {
            return Err(Refused("--speed paces --mode paced only".into()).into());
        }
        if let Some(protocol) = self.rc.take() {
            let set = ("rc.protocol".to_string(), toml::Value::String(protocol));
            self.profile.sets.sets.push(set);
        }
        let profile = self.profile.load_kept(self.log_dir.as_deref())?;
        let profile = with_mission(profile, self.mission.as_deref())?;
        let moves_radio = self.script.as_ref().is_some_and(|s| !s.1.is_empty());
        if moves_radio && profile.config.rc.protocol == config::RcProtocol::None {
            return Err(Refused(
                "--script moves the pilot's radio (sticks, switch) but rc.protocol is \"none\": \
                 add --rc sbus or --rc crsf"
                    .into(),
            )
            .into());
        }
        let opts = SimOptions {
            inject: self.inject,
            duration_s: self.duration,
            seed: self.seed,
            log_dir: self.log_dir,
            progress: true,
            script: self.script,
        };
        let summary = match mode {
            SimMode::Realtime => on_runtime(
                Duration::from_millis(200),
                uquad::app::sim_realtime::run(&profile, &opts),
            )
            .and_then(|r| r),
            SimMode::Fast => uquad::app::sim_fast::run_fast(&profile, &opts),
            SimMode::Paced => on_runtime(
                Duration::from_millis(200),
                uquad::app::sim_paced::run(&profile, &opts, self.speed.unwrap_or(1.0)),
            )
            .and_then(|r| r),
        };
        let summary = reported_failure(summary, self.report.as_deref())?;
        eprintln!("{}", summary.text());
        if let Some(path) = self.report {
            write_json(&summary.report(), &path)?;
        }
        Ok(exit_code(&summary.fly))
    }
}

impl CampaignArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let profile = self.profile.load_kept(None)?;
        let config = config::resolve_path(self.profile.config.as_deref()).map_err(Refused)?;
        let mission = self.mission.clone().unwrap_or_else(|| {
            let dir = config.parent().unwrap_or(Path::new("."));
            dir.join("missions").join("square.toml")
        });
        let jobs = self.jobs.map_or_else(
            || std::thread::available_parallelism().map_or(1, |n| n.get()),
            |j| j as usize,
        );
        let work_dir = std::env::temp_dir().join(format!("uquad-campaign-{}", std::process::id()));
        let opts = uquad::app::campaign::CampaignOptions {
            runs: self.runs,
            seed: self.seed,
            jobs,
            config,
            sets: self
                .profile
                .sets
                .sets
                .iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect(),
            mission,
            work_dir: work_dir.clone(),
        };
        let report = uquad::app::campaign::run(&profile, &opts);
        let _ = std::fs::remove_dir_all(&work_dir);
        let report = report?;
        println!("{}", report.text());
        if let Some(path) = self.report {
            write_json(&report, &path)?;
        }
        Ok(if report.violations.is_empty() {
            ExitCode::SUCCESS
        } else {
            ExitCode::FAILURE
        })
    }
}

impl ExportArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let files = uquad::app::export::run(&self.run_dir, self.format, &self.out)?;
        for f in files {
            println!("{}", f.display());
        }
        Ok(ExitCode::SUCCESS)
    }
}

impl NoiseArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        for (name, v) in [("--from", self.from), ("--to", self.to)] {
            if v.is_some_and(|v| !v.is_finite()) {
                anyhow::bail!("{name}: not a number of seconds");
            }
        }
        let report = uquad::app::noise::run(&uquad::app::noise::NoiseOptions {
            run_dir: self.run_dir,
            from_s: self.from,
            to_s: self.to,
            calib: self.calib,
        })?;
        print!("{}", report.text());
        if let Some(path) = &self.report {
            uquad::app::report::write_json(&report, path)?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

impl PlotArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let path = uquad::app::plot::run(&self.run_dir, self.out.as_deref())?;
        println!("{}", path.display());
        Ok(ExitCode::SUCCESS)
    }
}

impl ConsoleArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let path = match self.socket {
            Some(p) => p,
            None => {
                let cfg = config::resolve_path(None).map_err(anyhow::Error::msg)?;
                SetArgs { sets: vec![] }.load(&cfg)?.config.console.socket
            }
        };
        on_runtime(
            Duration::from_millis(100),
            uquad::console::attach(&path, self.filter.as_deref()),
        )??;
        Ok(ExitCode::SUCCESS)
    }
}

impl ReferenceArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        for path in uquad::app::reference::write(&self.out, &command_helps())? {
            println!("wrote {path}");
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// Each command's line and long help, the program's own first; at a fixed width of 100
/// columns, so the pages do not depend on the terminal they were written from.
fn command_helps() -> Vec<(String, String)> {
    use clap::CommandFactory;
    let mut cli = Cli::command().term_width(100);
    cli.build();
    let mut helps = vec![("uquad".to_string(), cli.render_long_help().to_string())];
    for sub in cli.get_subcommands_mut() {
        if sub.get_name() == "help" {
            continue;
        }
        let line = format!("uquad {}", sub.get_name());
        helps.push((line, sub.render_long_help().to_string()));
    }
    helps
}

impl ParamsArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let profile = self.profile.load_kept(self.log_dir.as_deref())?;
        let params = uquad::gcs::params::Params::of(&profile.config);
        println!(
            "{:<16}  {:<36}  {:>12}  flight-critical  takes effect",
            "id", "key", "value"
        );
        for i in 0..params.len() {
            if let Some(p) = params.get(i) {
                let critical = if p.flight_critical() { "yes" } else { "no" };
                let effect = if p.in_flight() { "flight" } else { "start" };
                println!(
                    "{:<16}  {:<36}  {:>12}  {critical:<15}  {effect}",
                    p.id, p.key, p.value
                );
            }
        }
        Ok(ExitCode::SUCCESS)
    }
}

impl GpsArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let mut stdout = std::io::stdout().lock();
        on_runtime(
            Duration::from_millis(100),
            uquad::app::gps::run(&self.gpsd, self.count, &mut stdout),
        )??;
        Ok(ExitCode::SUCCESS)
    }
}

impl LqrArgs {
    fn run(self) -> anyhow::Result<ExitCode> {
        let profile = self.profile.load()?;
        let integrators = self.integrators(&profile)?;
        let shape = self.shape()?;
        let outcome = uquad::app::lqr::run(&profile, integrators, shape, self.out.as_deref())?;
        println!("{}", uquad::app::lqr::describe_trim(&outcome.trim));
        println!(
            "closed-loop spectral radius {:.9} (relative Riccati residual {:.2e})",
            outcome.design.spectral_radius, outcome.design.residual_rel
        );
        match &outcome.files {
            Some((k_prop, k_int)) => {
                println!("{}", k_prop.display());
                println!("{}", k_int.display());
            }
            None => {
                use uquad::app::lqr::format_matrix;
                print!(
                    "K_prop (4 x 12):\n{}",
                    format_matrix(&outcome.design.k_prop())
                );
                print!("K_int (4 x 4):\n{}", format_matrix(&outcome.design.k_int()));
            }
        }
        Ok(ExitCode::SUCCESS)
    }

    fn integrators(&self, profile: &Profile) -> anyhow::Result<uquad::core::control::Integrators> {
        use uquad::core::control::Integrators;
        let list = match &self.integrators {
            Some(list) => list,
            None => &profile.config.control.integrators,
        };
        Integrators::parse(list)
            .filter(|s| *s != Integrators::ZTheta)
            .ok_or_else(|| {
                Refused(format!(
                    "--integrators {list:?}: expected psi,phi,z,theta or x,y,z,theta"
                ))
                .into()
            })
    }

    fn shape(&self) -> anyhow::Result<uquad::core::trim::PathShape> {
        use uquad::core::trim::PathShape;
        let positive = |v: Option<f64>, flag: &str| match v {
            Some(v) if v.is_finite() && v > 0.0 => Ok(v),
            Some(v) => Err(Refused(format!("{flag} {v}: must be a positive number"))),
            None => Err(Refused(
                format!("--path {:?} needs {flag}", self.path).to_lowercase(),
            )),
        };
        let course_rad = self.course_deg.to_radians();
        Ok(match self.path {
            LqrPath::Hover => PathShape::Hover,
            LqrPath::Straight => PathShape::Straight {
                speed_m_s: positive(self.speed, "--speed")?,
                course_rad,
            },
            LqrPath::Circle => PathShape::Circle {
                radius_m: positive(self.radius, "--radius")?,
                speed_m_s: positive(self.speed, "--speed")?,
                course_rad,
                left: self.turn == Turn::Left,
            },
        })
    }
}

impl ReplayArgs {
    /// The profile of `run_dir`: --config, else the run folder's own config.toml.
    fn profile(&self, run_dir: &Path) -> anyhow::Result<Profile> {
        let path = match &self.config {
            Some(p) => p.clone(),
            None => {
                let p = run_dir.join("config.toml");
                if !p.is_file() {
                    return Err(Refused(format!(
                        "{} has no config.toml; pass --config FILE (config/flight-2012-05.toml for the 2012 runs)",
                        run_dir.display()
                    ))
                    .into());
                }
                p
            }
        };
        self.sets.load(&path)
    }

    fn run(self) -> anyhow::Result<ExitCode> {
        match self.run_dirs.as_slice() {
            [one] => self.run_one(&one.clone()),
            _ => self.run_batch(),
        }
    }

    /// Many runs: each into OUT_DIR/<its name>; the throughput at the end; a failed run named,
    /// the exit status non-zero.
    fn run_batch(&self) -> anyhow::Result<ExitCode> {
        let fixed = match &self.config {
            Some(p) => Some(self.sets.load(p)?),
            None => None,
        };
        let profile = |run: &Path| match &fixed {
            Some(p) => Ok(p.clone()),
            None => self.profile(run),
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let s = uquad::app::replay_batch::run(&self.run_dirs, &self.out, threads, &profile);
        println!(
            "replayed {} of {} runs into {}: {} Kalman steps in {:.3} s on {} threads, {:.0} steps/s",
            s.runs - s.failed.len(),
            s.runs,
            self.out.display(),
            s.kalman_steps,
            s.wall_s,
            s.threads,
            s.steps_per_s()
        );
        for (run, why) in &s.failed {
            eprintln!("error: replay of {} failed: {why}", run.display());
        }
        Ok(if s.failed.is_empty() {
            ExitCode::SUCCESS
        } else {
            ExitCode::FAILURE
        })
    }

    fn run_one(&self, run_dir: &Path) -> anyhow::Result<ExitCode> {
        if uquad::app::replay::out_is_the_run_folder(run_dir, &self.out) {
            return Err(Refused(format!(
                "--out {}: that is the run folder being replayed, whose logs would be overwritten; choose another folder",
                self.out.display()
            ))
            .into());
        }
        // The profile is loaded while a second thread reads the run's logs; a profile refused
        // is said as it is (exit status 2), not as a replay that failed.
        let summary = uquad::app::replay::run_loading(run_dir, &self.out, || self.profile(run_dir))
            .map_err(|e| {
                if e.is::<Refused>() {
                    e
                } else {
                    e.context(format!("replay of {} failed", run_dir.display()))
                }
            })?;
        tracing::info!(
            raw_frames = summary.raw_frames,
            kalman_steps = summary.kalman_steps,
            gps_updates = summary.gps_updates,
            dt_clamped = summary.dt_clamped,
            ekf_errors = summary.ekf_errors,
            gated_attitude = summary.ekf_gated.attitude,
            gated_altitude = summary.ekf_gated.altitude,
            gated_gps = summary.ekf_gated.gps,
            "replay finished"
        );
        // One write for all the paths (a line at a time would be a write each).
        let paths: String = summary
            .outputs
            .iter()
            .map(|o| format!("{}\n", o.display()))
            .collect();
        print!("{paths}");
        Ok(ExitCode::SUCCESS)
    }
}

/// `--speed`: a finite factor in [0.1, 100].
fn parse_speed(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))?;
    if (0.1..=100.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is outside 0.1 to 100"))
    }
}
