//! `uquad replay RUN_DIR... --out OUT` over many run folders at once — a season's logs, a
//! parameter sweep: each run replayed into `OUT/<its folder's name>`, the runs spread over
//! every core, progress on stderr, the throughput at the end. A run that fails is named with
//! its reason and the others go on.

use crate::app::replay::{self, ReplaySummary};
use crate::config::Profile;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// What a batch did.
#[derive(Debug, Default)]
pub struct BatchSummary {
    pub runs: usize,
    pub kalman_steps: usize,
    /// The runs that failed, with why.
    pub failed: Vec<(PathBuf, String)>,
    pub threads: usize,
    pub wall_s: f64,
}

impl BatchSummary {
    pub fn steps_per_s(&self) -> f64 {
        self.kalman_steps as f64 / self.wall_s.max(1e-9)
    }
}

/// The output folder of each run: `out/<its name>`, a suffix `-2`, `-3`, … on a repeat.
pub fn out_dirs(runs: &[PathBuf], out: &Path) -> Vec<PathBuf> {
    let mut seen: Vec<String> = Vec::with_capacity(runs.len());
    runs.iter()
        .map(|r| {
            let base = r
                .canonicalize()
                .ok()
                .and_then(|c| c.file_name().map(|n| n.to_string_lossy().into_owned()))
                .unwrap_or_else(|| "run".to_string());
            let n = seen.iter().filter(|s| **s == base).count();
            seen.push(base.clone());
            match n {
                0 => out.join(base),
                n => out.join(format!("{base}-{}", n + 1)),
            }
        })
        .collect()
}

/// One run: refused if its output would be its own folder.
fn one(
    run: &Path,
    out: &Path,
    profile: &dyn Fn(&Path) -> anyhow::Result<Profile>,
) -> anyhow::Result<ReplaySummary> {
    if replay::out_is_the_run_folder(run, out) {
        anyhow::bail!(
            "{}: its output would be the run folder itself",
            out.display()
        );
    }
    let p = profile(run)?;
    replay::run_on_this_thread(run, &p, out)
}

/// Replays `runs` into their folders under `out` on `threads` threads; `profile` gives each
/// run's configuration.
pub fn run(
    runs: &[PathBuf],
    out: &Path,
    threads: usize,
    profile: &(dyn Fn(&Path) -> anyhow::Result<Profile> + Sync),
) -> BatchSummary {
    let outs = out_dirs(runs, out);
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let results: Mutex<Vec<(usize, anyhow::Result<usize>)>> = Mutex::new(Vec::new());
    let threads = threads.clamp(1, runs.len().max(1));
    let t0 = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let (Some(run), Some(out)) = (runs.get(i), outs.get(i)) else {
                        break;
                    };
                    // A panic in one replay fails that run only (and the progress still ends).
                    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        one(run, out, profile).map(|s| s.kalman_steps)
                    }))
                    .unwrap_or_else(|_| Err(anyhow::anyhow!("the replay panicked")));
                    if let Ok(mut v) = results.lock() {
                        v.push((i, r));
                    }
                    done.fetch_add(1, Ordering::Relaxed);
                }
            });
        }
        progress(&done, runs.len(), t0);
    });
    let mut summary = BatchSummary {
        runs: runs.len(),
        threads,
        wall_s: t0.elapsed().as_secs_f64(),
        ..BatchSummary::default()
    };
    let mut results = results.into_inner().unwrap_or_default();
    results.sort_by_key(|(i, _)| *i);
    for (i, r) in results {
        match r {
            Ok(steps) => summary.kalman_steps += steps,
            Err(e) => summary.failed.push((runs[i].clone(), format!("{e:#}"))),
        }
    }
    summary
}

/// A progress line on stderr while the runs go, when it is a terminal.
fn progress(done: &AtomicUsize, total: usize, t0: Instant) {
    if !std::io::stderr().is_terminal() {
        return;
    }
    loop {
        let n = done.load(Ordering::Relaxed);
        let bar = "#".repeat(30 * n / total.max(1));
        eprint!(
            "\rreplaying [{bar:<30}] {n}/{total} runs, {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        if n >= total {
            eprintln!();
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_names_get_a_suffix() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        let b = dir.path().join("x").join("a");
        std::fs::create_dir_all(&a).unwrap();
        std::fs::create_dir_all(&b).unwrap();
        let outs = out_dirs(&[a.clone(), b, a], Path::new("/o"));
        assert_eq!(
            outs,
            [
                PathBuf::from("/o/a"),
                PathBuf::from("/o/a-2"),
                PathBuf::from("/o/a-3")
            ]
        );
    }
}
