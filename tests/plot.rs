//! `uquad plot` of the original's 2012 flight and of a simulated run.

mod common;
use common::*;

/// Checks a written SVG: one polyline per expected series, each with many points and finite
/// coordinates, and every series named in a legend.
fn check_svg(path: &std::path::Path) {
    let svg = std::fs::read_to_string(path).unwrap();
    assert!(svg.starts_with("<svg xmlns=\"http://www.w3.org/2000/svg\""));
    assert!(svg.trim_end().ends_with("</svg>"));
    let expected = [
        "z",
        "roll psi",
        "pitch phi",
        "yaw theta",
        "m0",
        "m1",
        "m2",
        "m3",
    ];
    let lines: Vec<&str> = svg.lines().filter(|l| l.starts_with("<polyline")).collect();
    assert_eq!(lines.len(), expected.len());
    for (line, name) in lines.iter().zip(expected) {
        assert!(
            line.contains(&format!("data-series=\"{name}\"")),
            "{line:.80}"
        );
        let points = line
            .split("points=\"")
            .nth(1)
            .unwrap()
            .trim_end_matches("\"/>");
        let n = points.split_whitespace().count();
        assert!(n > 500, "{name}: {n} points");
        for p in points.split_whitespace() {
            let (x, y) = p.split_once(',').unwrap();
            let (x, y): (f64, f64) = (x.parse().unwrap(), y.parse().unwrap());
            assert!(x.is_finite() && y.is_finite());
        }
        // The legend entry: the name drawn as glyph pixels (a path of squares), titled.
        let title = format!("<title>{name}</title></path>");
        let legend = svg
            .lines()
            .find(|l| l.starts_with("<line") && l.contains(&title))
            .unwrap_or_else(|| panic!("legend for {name}"));
        assert!(legend.matches('M').count() >= 3 * name.len(), "{legend}");
    }
    // No typeset text: nothing for a viewer to find a font for.
    assert!(!svg.contains("<text") && !svg.contains("font-family"));
    assert_eq!(svg.matches('<').count(), svg.matches('>').count());
}

#[test]
fn plots_the_2012_flight() {
    let out = tempfile::tempdir().unwrap();
    let svg = out.path().join("flight.svg");
    let o = uquad(
        &root(),
        &[
            "plot",
            flight_dir().to_str().unwrap(),
            "--out",
            svg.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_svg(&svg);
    // PNG is refused with the reason, nothing written.
    let png = out.path().join("flight.png");
    let o = uquad(
        &root(),
        &[
            "plot",
            flight_dir().to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("only SVG"));
    assert!(!png.exists());
}

#[test]
fn plots_a_sim_run() {
    let logs = tempfile::tempdir().unwrap();
    let o = uquad(
        &root(),
        &[
            "sim",
            "--duration",
            "20",
            "--log-dir",
            logs.path().to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = std::fs::read_dir(logs.path())
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let o = uquad(&root(), &["plot", run.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_svg(&run.join("plot.svg"));
}
