//! `uquad lqr`: hover gains by LQR, checked against an independent solution.

mod common;
use common::*;

fn matrix(path: &std::path::Path) -> Vec<Vec<f64>> {
    numbers(path)
}

/// `a` and `b` have the same shape and agree to `rel` of `b`'s largest entry.
fn assert_close(a: &[Vec<f64>], b: &[Vec<f64>], rel: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    let scale = b.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for (ra, rb) in a.iter().zip(b) {
        assert_eq!(ra.len(), rb.len(), "{what}");
        for (x, y) in ra.iter().zip(rb) {
            assert!((x - y).abs() <= rel * scale, "{what}: {x} vs {y}");
        }
    }
}

/// The spectral radius and residual from "closed-loop spectral radius R (relative Riccati
/// residual E)".
fn design_figures(stdout: &str) -> (f64, f64) {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("closed-loop spectral radius"))
        .unwrap_or_else(|| panic!("no design line in {stdout}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let rho = words[3].parse().unwrap();
    let residual = words[7].trim_end_matches(')').parse().unwrap();
    (rho, residual)
}

#[test]
fn xyzt_design_matches_an_independent_solution() {
    let out = tempfile::tempdir().unwrap();
    let o = uquad(
        &root(),
        &[
            "lqr",
            "--config",
            "config/flight-2012-05.toml",
            "--integrators",
            "x,y,z,theta",
            "--out",
            out.path().to_str().unwrap(),
        ],
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (rho, residual) = design_figures(&stdout);
    assert!(rho < 1.0 && rho > 0.9, "{stdout}");
    assert!(residual < 1e-9, "{stdout}");

    // SciPy's Schur-method DARE solver on the same model (tests/data/lqr/reference.py).
    for (ours, theirs, rows, cols) in [
        ("K_prop.txt", "K_prop_xyzt.txt", 4, 12),
        ("K_int.txt", "K_int_xyzt.txt", 4, 4),
    ] {
        let a = matrix(&out.path().join(ours));
        let b = matrix(&root().join("tests/data/lqr").join(theirs));
        assert_eq!(a.len(), rows);
        assert!(a.iter().all(|r| r.len() == cols), "{ours}");
        assert_close(&a, &b, 1e-9, ours);
    }

    // The gains load as the controller's gain files.
    let o = uquad(
        &root(),
        &[
            "check-config",
            "config/flight-2012-05.toml",
            "--set",
            &format!(
                "control.k_prop_file=\"{}\"",
                out.path().join("K_prop.txt").display()
            ),
            "--set",
            &format!(
                "control.k_int_file=\"{}\"",
                out.path().join("K_int.txt").display()
            ),
            "--set",
            "control.integrators=x,y,z,theta",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn library_design_residual_and_stability() {
    let profile = uquad::config::load(&profile_2012(), &[]).unwrap();
    let q = uquad::core::lqr::Mat16::from_row_slice(&profile.lqr_q);
    let r = uquad::core::lqr::Mat4::from_row_slice(&profile.lqr_r);
    let d = uquad::core::lqr::design(1.55, uquad::core::control::Integrators::XYZTheta, &q, &r)
        .unwrap();
    let (phi, gamma) = &d.discrete;
    let residual = uquad::core::lqr::dare_residual(phi, gamma, &q, &r, &d.p);
    assert!(residual < 1e-9, "{residual}");
    let rho = (phi - gamma * d.k_lqr)
        .complex_eigenvalues()
        .iter()
        .map(|c| c.norm())
        .fold(0.0, f64::max);
    assert!(rho < 1.0, "{rho}");
}

#[test]
fn psi_phi_design_is_refused_with_the_reason() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("gains");
    // The default integrators are psi,phi,z,theta.
    let o = uquad(
        &root(),
        &[
            "lqr",
            "--config",
            "config/flight-2012-05.toml",
            "--out",
            dir.to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("not stabilisable"), "{err}");
    assert!(err.contains("unit circle"), "{err}");
    assert!(err.contains("vqx − g·∫φ"), "{err}");
    assert!(err.contains("--integrators x,y,z,theta"), "{err}");
    assert!(!dir.exists(), "nothing is written");
    // A list it does not know is refused too.
    let o = uquad(
        &root(),
        &[
            "lqr",
            "--integrators",
            "z,theta",
            "--out",
            dir.to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--integrators"));
}

#[test]
fn the_default_profile_gains_are_its_lqr_design() {
    // config/uquad.toml flies K_*_lqr_xyzt.txt: they must be what `uquad lqr` designs from the
    // profile's own weights, so anyone can change the weights and regenerate them.
    let out = tempfile::tempdir().unwrap();
    let o = uquad(
        &root(),
        &[
            "lqr",
            "--config",
            "config/uquad.toml",
            "--integrators",
            "x,y,z,theta",
            "--out",
            out.path().to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (ours, shipped) in [
        ("K_prop.txt", "K_prop_lqr_xyzt.txt"),
        ("K_int.txt", "K_int_lqr_xyzt.txt"),
    ] {
        let a = matrix(&out.path().join(ours));
        let b = matrix(&root().join("config").join(shipped));
        assert_close(&a, &b, 1e-12, shipped);
    }
}

#[test]
fn path_designs_match_an_independent_solution() {
    // `uquad lqr --path straight --speed 1` and `--path circle --radius 5 --speed 1` on the
    // default profile, against SciPy's trim and Schur-method DARE on the same model
    // (tests/data/lqr/path_reference.py).
    for (args, case) in [
        (&["--path", "straight", "--speed", "1"][..], "straight_v1"),
        (
            &["--path", "circle", "--radius", "5", "--speed", "1"][..],
            "circle_r5_v1",
        ),
    ] {
        let out = tempfile::tempdir().unwrap();
        let mut all = vec!["lqr", "--out", out.path().to_str().unwrap()];
        all.extend_from_slice(args);
        let o = uquad(&root(), &all);
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (rho, residual) = design_figures(&stdout);
        assert!(rho < 1.0, "{case}: {stdout}");
        assert!(residual <= 1e-9, "{case}: {stdout}");
        for (ours, theirs) in [
            ("K_prop.txt", format!("K_prop_{case}.txt")),
            ("K_int.txt", format!("K_int_{case}.txt")),
        ] {
            let a = matrix(&out.path().join(ours));
            let b = matrix(&root().join("tests/data/lqr").join(&theirs));
            assert_close(&a, &b, 1e-9, &theirs);
        }
    }
    // Without --out the gains are printed; a circle without its radius is refused by name.
    let o = uquad(&root(), &["lqr", "--path", "straight", "--speed", "1"]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("K_prop (4 x 12):"));
    let o = uquad(&root(), &["lqr", "--path", "circle", "--speed", "1"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("needs --radius"));
}
