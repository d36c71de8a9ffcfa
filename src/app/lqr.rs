//! `uquad lqr`: designs hover gains from the vehicle model and writes them as gain files.

use crate::config::Profile;
use crate::core::control::Integrators;
use crate::core::lqr::{self, Design, Mat4, Mat16};
use anyhow::{Context, bail};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What a design wrote.
#[derive(Debug, Clone)]
pub struct LqrOutcome {
    pub design: Design,
    pub k_prop_path: PathBuf,
    pub k_int_path: PathBuf,
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

/// Designs the gains for `profile` with `integrators` and writes `K_prop.txt` and `K_int.txt`
/// into `out_dir`. Nothing is written when the design fails.
pub fn run(
    profile: &Profile,
    integrators: Integrators,
    out_dir: &Path,
) -> anyhow::Result<LqrOutcome> {
    if integrators == Integrators::ZTheta {
        bail!("the LQR design covers the 12-state controller: use psi,phi,z,theta or x,y,z,theta");
    }
    let q = Mat16::from_row_slice(&profile.lqr_q);
    let r = Mat4::from_row_slice(&profile.lqr_r);
    let design = lqr::design(profile.config.vehicle.mass_kg, integrators, &q, &r)?;
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let k_prop_path = out_dir.join("K_prop.txt");
    let k_int_path = out_dir.join("K_int.txt");
    std::fs::write(&k_prop_path, format_matrix(&design.k_prop()))
        .with_context(|| format!("cannot write {}", k_prop_path.display()))?;
    std::fs::write(&k_int_path, format_matrix(&design.k_int()))
        .with_context(|| format!("cannot write {}", k_int_path.display()))?;
    Ok(LqrOutcome {
        design,
        k_prop_path,
        k_int_path,
    })
}
