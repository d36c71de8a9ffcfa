//! `uquad lqr`: designs gains from the vehicle model, at hover or about a path's trim, and
//! prints them or writes them as gain files.

use crate::config::Profile;
use crate::core::control::Integrators;
use crate::core::lqr::{self, Design, Mat4, Mat16};
use crate::core::trim::{self, PathShape, Trim};
use anyhow::{Context, bail};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What a design gave, and the gain files it wrote (with an output folder).
#[derive(Debug, Clone)]
pub struct LqrOutcome {
    pub design: Design,
    pub trim: Trim,
    pub files: Option<(PathBuf, PathBuf)>,
}

/// Formats a matrix as a gain file: one row per line, numbers separated by tabs, printed with
/// 17 significant digits so they read back exactly.
pub fn format_matrix<const R: usize, const C: usize>(m: &nalgebra::SMatrix<f64, R, C>) -> String {
    let mut out = String::new();
    for r in 0..R {
        for c in 0..C {
            if c > 0 {
                out.push('\t');
            }
            let _ = write!(out, "{:.16e}", m[(r, c)]);
        }
        out.push('\n');
    }
    out
}

/// Designs the gains for `profile` with `integrators` about `shape`'s trim, and writes
/// `K_prop.txt` and `K_int.txt` into `out_dir` when one is given. Nothing is written when the
/// design fails. Hover uses the hover model as before (the default profile's gain files are
/// that design).
pub fn run(
    profile: &Profile,
    integrators: Integrators,
    shape: PathShape,
    out_dir: Option<&Path>,
) -> anyhow::Result<LqrOutcome> {
    if integrators == Integrators::ZTheta {
        bail!("the LQR design covers the 12-state controller: use psi,phi,z,theta or x,y,z,theta");
    }
    let q = Mat16::from_row_slice(&profile.lqr_q);
    let r = Mat4::from_row_slice(&profile.lqr_r);
    let mass_kg = profile.config.vehicle.mass_kg;
    let trim = trim::trim(shape, mass_kg)?;
    let design = match shape {
        PathShape::Hover => lqr::design(mass_kg, integrators, &q, &r)?,
        _ => lqr::design_path(mass_kg, &trim, integrators, &q, &r)?,
    };
    let files = out_dir.map(|dir| write_gains(&design, dir)).transpose()?;
    Ok(LqrOutcome {
        design,
        trim,
        files,
    })
}

fn write_gains(design: &Design, out_dir: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let k_prop_path = out_dir.join("K_prop.txt");
    let k_int_path = out_dir.join("K_int.txt");
    std::fs::write(&k_prop_path, format_matrix(&design.k_prop()))
        .with_context(|| format!("cannot write {}", k_prop_path.display()))?;
    std::fs::write(&k_int_path, format_matrix(&design.k_int()))
        .with_context(|| format!("cannot write {}", k_int_path.display()))?;
    Ok((k_prop_path, k_int_path))
}

/// The trim as `uquad lqr` prints it.
pub fn describe_trim(t: &Trim) -> String {
    // Rounding noise prints as 0, not as −0.
    let z = |v: f64| if v.abs() < 1e-12 { 0.0 } else { v };
    let deg = |r: f64| z(r.to_degrees());
    let (v, w) = (t.v_body_m_s.map(z), t.w_body_rad_s.map(z));
    format!(
        "trim: roll {:.4}° pitch {:.4}° yaw rate {:.6} rad/s\n\
         body velocity [{:.6}, {:.6}, {:.6}] m/s, body rates [{:.6}, {:.6}, {:.6}] rad/s\n\
         motors [{:.4}, {:.4}, {:.4}, {:.4}] rad/s",
        deg(t.psi_rad),
        deg(t.phi_rad),
        z(t.yaw_rate_rad_s),
        v[0],
        v[1],
        v[2],
        w[0],
        w[1],
        w[2],
        t.w_motor_rad_s[0],
        t.w_motor_rad_s[1],
        t.w_motor_rad_s[2],
        t.w_motor_rad_s[3],
    )
}
