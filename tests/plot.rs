//! `uquad plot` of the original's 2012 flight and of a simulated run: what is drawn (the
//! figure's content, read from the run folder) and the files written (PNG and SVG).

mod common;
use common::*;
use std::path::Path;

/// A PNG's width and height, from its header.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(
        &b[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is not a PNG",
        path.display()
    );
    assert_eq!(&b[12..16], b"IHDR");
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    (be(16), be(20))
}

/// Plots `run` into `name` in a fresh folder; returns the file and its folder.
fn plot(run: &Path, name: &str) -> (std::path::PathBuf, tempfile::TempDir) {
    let out = tempfile::tempdir().unwrap();
    let file = out.path().join(name);
    let o = uquad(
        &root(),
        &[
            "plot",
            run.to_str().unwrap(),
            "--out",
            file.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (file, out)
}

/// Every panel is titled and every axis named with its unit.
fn check_svg(path: &Path) {
    let svg = std::fs::read_to_string(path).unwrap();
    assert!(svg.contains("<svg"), "{svg:.200}");
    // The texts: what each <text> element holds.
    let texts: Vec<&str> = svg
        .split("<text")
        .skip(1)
        .filter_map(|t| t.split_once('>')?.1.split_once("</text>"))
        .map(|(inner, _)| inner.trim())
        .collect();
    for text in [
        "altitude",
        "roll and pitch",
        "yaw",
        "motor speeds",
        "horizontal track",
        "time (s)",
        "z (m, up)",
        "angle (rad)",
        "θ (rad)",
        "ω (rad/s)",
        "east (m)",
        "north (m)",
        "motor 3",
    ] {
        assert!(texts.contains(&text), "no text {text:?} in {texts:?}");
    }
}

#[test]
fn plots_the_2012_flight() {
    let fig = uquad::app::plot::figure(&flight_dir()).unwrap();
    let names: Vec<Vec<&str>> = fig
        .panels
        .iter()
        .map(|p| p.series.iter().map(|s| s.name.as_str()).collect())
        .collect();
    // The original logged no set points and no modes.
    assert_eq!(
        names,
        [
            vec!["z"],
            vec!["roll ψ", "pitch φ"],
            vec!["yaw θ"],
            vec!["motor 0", "motor 1", "motor 2", "motor 3"]
        ]
    );
    assert!(
        fig.panels
            .iter()
            .all(|p| p.series.iter().all(|s| s.points.len() > 500))
    );
    assert!(fig.marks.is_empty() && fig.track.len() == 1);
    assert!(fig.panels.iter().all(|p| p.series.iter().all(|s| !s.truth)));
    let (png, _dir) = plot(&flight_dir(), "flight.png");
    assert_eq!(png_size(&png), (1600, 1200));
    let (svg, _dir) = plot(&flight_dir(), "flight.svg");
    check_svg(&svg);
    // Another extension is refused with the reason, nothing written.
    let jpg = _dir.path().join("flight.jpg");
    let o = uquad(
        &root(),
        &[
            "plot",
            flight_dir().to_str().unwrap(),
            "--out",
            jpg.to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("flight.jpg") && err.contains(".png or .svg"),
        "{err}"
    );
    assert!(!jpg.exists());
}

#[test]
fn plots_a_sim_run_with_its_set_points_modes_and_track() {
    let logs = tempfile::tempdir().unwrap();
    let run = sim_run(logs.path(), &[]);
    let fig = uquad::app::plot::figure(&run).unwrap();
    for p in &fig.panels[..3] {
        let set: Vec<_> = p.series.iter().filter(|s| s.setpoint).collect();
        assert!(
            !set.is_empty() && set.iter().all(|s| s.points.len() > 500),
            "{}",
            p.title
        );
    }
    let labels: Vec<&str> = fig.marks.iter().map(|m| m.label.as_str()).collect();
    assert_eq!(
        labels,
        ["disarmed", "armed", "takeoff", "hold", "land", "disarmed"]
    );
    assert_eq!(fig.track.len(), 3, "flown, planned and the truth");
    // A sim run has truth.log: each pose panel draws it beside the estimate, and a panel of
    // the innovation test ratios has the gate.
    for p in &fig.panels[..3] {
        let truth: Vec<_> = p.series.iter().filter(|s| s.truth).collect();
        assert!(
            !truth.is_empty() && truth.iter().all(|s| s.points.len() > 500),
            "{}",
            p.title
        );
    }
    let ratios = fig.panels.last().unwrap();
    let names: Vec<&str> = ratios.series.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["attitude", "altitude", "gps", "gate (ratio 1)"]);
    assert!(ratios.series[0].points.len() > 500);
    // The default output is RUN_DIR/plot.png.
    let o = uquad(&root(), &["plot", run.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png_size(&run.join("plot.png")), (1600, 1200));
    let (svg, _dir) = plot(&run, "run.svg");
    check_svg(&svg);
}
