//! The GPS path against a real gpsd (Debian's `gpsd`, installed by tests/run.sh), fed over a
//! `tcp://` source this test owns with NMEA it generates from the 2012 GPX track.

mod common;
use common::*;
use std::process::{Child, Command, Stdio};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;

/// The 2012 Montevideo track: (lat, lon, ele) of each point.
fn gpx_track() -> Vec<(f64, f64, f64)> {
    let text =
        std::fs::read_to_string(root().join("tests/data/gpx-2012-01-30-montevideo.gpx")).unwrap();
    let mut out = Vec::new();
    for part in text.split("<trkpt ").skip(1) {
        let attr = |name: &str| -> f64 {
            let start = part.find(&format!("{name}=\"")).unwrap() + name.len() + 2;
            let end = start + part[start..].find('"').unwrap();
            part[start..end].parse().unwrap()
        };
        let ele = part
            .split("<ele>")
            .nth(1)
            .and_then(|e| e.split("</ele>").next())
            .unwrap()
            .parse()
            .unwrap();
        out.push((attr("lat"), attr("lon"), ele));
    }
    assert_eq!(out.len(), 24, "the track has 24 points");
    out
}

fn nmea(body: &str) -> String {
    let cs = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{cs:02X}\r\n")
}

/// RMC + GGA + GSA for one point at second `k` (ddmm.mmmm format, hemispheres from signs).
fn sentences(k: usize, (lat, lon, ele): (f64, f64, f64)) -> String {
    let dm = |v: f64| {
        let a = v.abs();
        let d = a.trunc();
        d * 100.0 + (a - d) * 60.0
    };
    let (ns, ew) = (
        if lat < 0.0 { 'S' } else { 'N' },
        if lon < 0.0 { 'W' } else { 'E' },
    );
    let t = format!("{:02}{:02}{:02}.00", 23, 3 + k / 60 % 60, k % 60);
    let (la, lo) = (dm(lat), dm(lon));
    nmea(&format!(
        "GPRMC,{t},A,{la:09.4},{ns},{lo:010.4},{ew},0.0,0.0,300112,,,A"
    )) + &nmea(&format!(
        "GPGGA,{t},{la:09.4},{ns},{lo:010.4},{ew},1,10,0.9,{ele:.1},M,14.0,M,,"
    )) + &nmea("GPGSA,A,3,01,02,03,04,05,06,07,08,09,10,,,1.6,0.9,1.3")
}

/// Serves the track, again and again, to every connection (gpsd reconnects after a restart),
/// a point every 50 ms (faster than real time, so the tests stay short).
async fn nmea_source(listener: TcpListener) {
    let track = gpx_track();
    let mut k = 0usize;
    while let Ok((mut conn, _)) = listener.accept().await {
        loop {
            let s = sentences(k, track[k % track.len()]);
            k += 1;
            if conn.write_all(s.as_bytes()).await.is_err() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

/// One gpsd and one flight at a time: a flight shares this 2-core machine with nothing else.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A gpsd process, stopped when dropped (also when a test fails).
/// A gpsd for one test; its stderr is kept and printed if the test fails.
struct Gpsd(Child, tempfile::NamedTempFile);

impl Gpsd {
    fn start(port: u16, source_port: u16) -> Gpsd {
        let bin = ["/usr/sbin/gpsd", "/usr/bin/gpsd"]
            .into_iter()
            .find(|p| std::path::Path::new(p).exists())
            .unwrap_or("gpsd");
        let stderr = tempfile::NamedTempFile::new().unwrap();
        let child = Command::new(bin)
            .args(["-N", "-n", "-S", &port.to_string()])
            .arg(format!("tcp://127.0.0.1:{source_port}"))
            .stdout(Stdio::null())
            .stderr(stderr.reopen().unwrap())
            .spawn()
            .unwrap_or_else(|e| {
                panic!("cannot start gpsd ({bin}): {e}; tests/run.sh installs Debian's gpsd")
            });
        Gpsd(child, stderr)
    }
}

impl Drop for Gpsd {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        if std::thread::panicking() {
            let text = std::fs::read_to_string(self.1.path()).unwrap_or_default();
            eprintln!("--- gpsd's stderr ---\n{text}");
        }
    }
}

async fn source() -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    tokio::spawn(nmea_source(listener));
    port
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uquad_gps_prints_the_streams_fixes() {
    let _one = ONE_AT_A_TIME.lock().await;
    let src = source().await;
    let port = free_port();
    let _gpsd = Gpsd::start(port, src);
    let server = format!("127.0.0.1:{port}");
    // gpsd needs a moment to listen.
    let mut out = None;
    for _ in 0..50 {
        let o = tokio::task::spawn_blocking({
            let server = server.clone();
            move || uquad(&root(), &["gps", "--gpsd", &server, "--count", "5"])
        })
        .await
        .unwrap();
        if o.status.success() {
            out = Some(o);
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let o = out.expect("uquad gps never got 5 fixes");
    let track = gpx_track();
    let stdout = String::from_utf8(o.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    let fixes: Vec<serde_json::Value> = lines
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for f in &fixes {
        let mode = f["mode"].as_u64().unwrap();
        assert!(mode == 2 || mode == 3, "{f}");
        let (lat, lon) = (
            f["lat_deg"].as_f64().unwrap(),
            f["lon_deg"].as_f64().unwrap(),
        );
        assert!(
            track
                .iter()
                .any(|p| (p.0 - lat).abs() < 1e-6 && (p.1 - lon).abs() < 1e-6),
            "{lat} {lon} is not a point of the stream"
        );
        for k in ["x_m", "y_m"] {
            assert!(f[k].is_f64(), "{k} missing: {f}");
        }
        // gpsd may open with a 2D fix, whose altitude it does not give (`null`, as the
        // book says: docs/src/install.md); a 3D fix always has one.
        for k in ["alt_m", "z_m"] {
            assert!(
                f[k].is_f64() || (mode == 2 && f[k].is_null()),
                "{k} missing: {f}"
            );
        }
    }
    // The local frame: the first fix is the origin; later ones are north/west of it as the
    // coordinates say. The frame follows the UTM grid, turned by the grid convergence (0.48°
    // here, 0.84° from the zone's central meridian), so allow 1.2 % of the distance.
    assert_eq!(fixes[0]["x_m"], 0.0);
    let lat0 = fixes[0]["lat_deg"].as_f64().unwrap();
    let lon0 = fixes[0]["lon_deg"].as_f64().unwrap();
    for f in &fixes[1..] {
        let north = (f["lat_deg"].as_f64().unwrap() - lat0).to_radians() * 6_356_000.0;
        let west = -(f["lon_deg"].as_f64().unwrap() - lon0).to_radians()
            * 6_384_000.0
            * lat0.to_radians().cos();
        let tol = 0.02 + 0.012 * north.hypot(west);
        assert!(
            (f["x_m"].as_f64().unwrap() - north).abs() < tol,
            "{f} vs north {north}"
        );
        assert!(
            (f["y_m"].as_f64().unwrap() - west).abs() < tol,
            "{f} vs west {west}"
        );
    }
    // Logs went to stderr, not stdout.
    assert!(!stdout.contains("INFO"));
}

#[test]
fn uquad_gps_without_gpsd_fails_clearly() {
    let port = free_port();
    let o = uquad(
        &root(),
        &[
            "gps",
            "--gpsd",
            &format!("127.0.0.1:{port}"),
            "--count",
            "1",
        ],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("cannot reach gpsd") && err.contains(&port.to_string()),
        "{err}"
    );
    assert!(o.stdout.is_empty());
}

/// Positions fused by the estimator, from the run's gps.log: (lat, lon, x, y).
fn fused(run_dir: &std::path::Path) -> Vec<(f64, f64, f64, f64)> {
    let text = std::fs::read_to_string(run_dir.join("gps.log")).unwrap();
    assert!(text.starts_with(uquad::logs::UQUAD_GPS_HEADER));
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<f64> = l.split_whitespace().map(|v| v.parse().unwrap()).collect();
            (f[9], f[10], f[3], f[4])
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gpsd_fixes_reach_the_estimator_and_the_run_replays() {
    let _one = ONE_AT_A_TIME.lock().await;
    let src = source().await;
    let port = free_port();
    let _gpsd = Gpsd::start(port, src);
    let server = format!("gps.server=\"127.0.0.1:{port}\"");
    let (summary, _, _, _logs) = fly_for(
        &["gps.mode=gpsd", &server],
        None,
        tokio::time::sleep(Duration::from_millis(5_500)),
    )
    .await;
    assert!(summary.error.is_none(), "{:?}", summary.error);
    assert!(summary.gpsd_fixes > 20, "{} fixes", summary.gpsd_fixes);
    assert!(summary.gps_updates > 20, "{} fused", summary.gps_updates);
    let f = fused(&summary.run_dir);
    assert_eq!(f.len() as u64, summary.gps_updates);
    let track = gpx_track();
    for &(lat, lon, _, _) in &f {
        assert!(
            track
                .iter()
                .any(|p| (p.0 - lat).abs() < 1e-6 && (p.1 - lon).abs() < 1e-6),
            "{lat} {lon} is not a point of the stream"
        );
    }
    // The positions the filter got agree with the coordinates (differences between fixes;
    // the UTM grid is turned by 0.48° here, hence 1.2 % of the distance).
    let (lat0, lon0, x0, y0) = f[0];
    for &(lat, lon, x, y) in &f[1..] {
        let north = (lat - lat0).to_radians() * 6_356_000.0;
        let west = -(lon - lon0).to_radians() * 6_384_000.0 * lat0.to_radians().cos();
        let tol = 0.02 + 0.012 * north.hypot(west);
        assert!(((x - x0) - north).abs() < tol, "x {x} vs {north}");
        assert!(((y - y0) - west).abs() < tol, "y {y} vs {west}");
    }
    // The run, gpsd fixes included, replays to the same bytes.
    let out = tempfile::tempdir().unwrap();
    let o = uquad(
        &root(),
        &[
            "replay",
            summary.run_dir.to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for name in ["x_hat.log", "w.log", "innov.log"] {
        assert_eq!(
            std::fs::read(summary.run_dir.join(name)).unwrap(),
            std::fs::read(out.path().join(name)).unwrap(),
            "{name}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gpsd_restart_mid_run_reconnects_and_loses_no_control_step() {
    let _one = ONE_AT_A_TIME.lock().await;
    let src = source().await;
    let port = free_port();
    let gpsd = Gpsd::start(port, src);
    let server = format!("gps.server=\"127.0.0.1:{port}\"");
    let (summary, _, _, _logs) = fly_for(&["gps.mode=gpsd", &server], None, async move {
        tokio::time::sleep(Duration::from_millis(3_500)).await;
        drop(gpsd); // gpsd goes away mid-flight
        tokio::time::sleep(Duration::from_millis(700)).await;
        let again = Gpsd::start(port, src);
        tokio::time::sleep(Duration::from_millis(3_300)).await;
        drop(again);
    })
    .await;
    assert!(summary.error.is_none(), "{:?}", summary.error);
    assert!(summary.gpsd_disconnects >= 1, "{summary:?}");
    assert!(summary.gpsd_connects >= 2, "{summary:?}");
    // No control step lost: every step was controlled and logged, none waited.
    let steps = summary.steps;
    assert!(steps > 250, "{steps}");
    // A control path that waited on the lost gpsd would drop most of its 700 ms absence (the
    // frames' queue holds 8) and be late for the rest (about 70 steps); a stall of this
    // shared machine drops or delays one or two.
    assert!(
        summary.dropped_frames * 100 <= steps,
        "{} dropped of {steps}",
        summary.dropped_frames
    );
    assert!(
        summary.late_feedback * 100 <= steps,
        "{} late of {steps}",
        summary.late_feedback
    );
    assert_eq!(
        read_table(&summary.run_dir.join("w.log")).len() as u64,
        steps
    );
    assert_eq!(summary.log_drops_total(), 0);
    // Fixes were fused again after the restart (the last second of the run).
    let times: Vec<f64> = std::fs::read_to_string(summary.run_dir.join("gps.log"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    let w = read_table(&summary.run_dir.join("w.log"));
    let t_end: f64 = w.last().unwrap()[0].parse().unwrap();
    assert!(
        times.iter().any(|&t| t > t_end - 1.0),
        "no fix fused after the restart: {times:?} (end {t_end})"
    );
}
