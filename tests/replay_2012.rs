//! Replay of the real 2012-05-25 flight reproduces the original program's `kalman_in.log`; many
//! copies of it replay at once, each into its own folder.

mod common;
use common::*;

#[test]
fn replay_reproduces_original_kalman_in() {
    let out = tempfile::tempdir().unwrap();
    let out_dir = out.path().join("new/sub"); // created by the replay
    let o = uquad(
        &root(),
        &[
            "replay",
            flight_dir().to_str().unwrap(),
            "--config",
            profile_2012().to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ours = read_table(&out_dir.join("kalman_in.log"));
    let theirs = read_table(&flight_dir().join("kalman_in.log"));
    assert_eq!(ours.len(), theirs.len(), "row count");
    assert_eq!(ours.len(), 1120);
    let mut worst = 0.0f64;
    for (k, (a, b)) in ours.iter().zip(&theirs).enumerate() {
        assert_eq!(a.len(), 14, "row {}", k + 1);
        assert_eq!(a[0], b[0], "time of row {}", k + 1);
        assert_eq!(a[1], b[1], "dt of row {}", k + 1);
        for col in 3..14 {
            let x: f64 = a[col].parse().unwrap();
            let y: f64 = b[col].parse().unwrap();
            worst = worst.max((x - y).abs());
            assert!(
                (x - y).abs() <= 1e-6,
                "row {} column {}: ours {x}, original {y}",
                k + 1,
                col + 1
            );
        }
    }
    // The port reproduces the printed values exactly.
    assert!(worst < 1e-8, "largest difference {worst}");
}

#[test]
fn replay_is_deterministic_and_overwrites() {
    let out = tempfile::tempdir().unwrap();
    std::fs::write(out.path().join("kalman_in.log"), "stale\n").unwrap();
    let run = || {
        let o = uquad(
            &root(),
            &[
                "replay",
                flight_dir().to_str().unwrap(),
                "--config",
                profile_2012().to_str().unwrap(),
                "--out",
                out.path().to_str().unwrap(),
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out.path().join("kalman_in.log")).unwrap()
    };
    let first = run();
    assert!(!first.starts_with(b"stale"));
    assert_eq!(first, run());
    // Files longer than what the replay writes are cut to it, not left with a stale tail.
    let [x_hat, mode] =
        ["x_hat.log", "mode.log"].map(|f| std::fs::read(out.path().join(f)).unwrap());
    let mut longer = x_hat.clone();
    longer.extend_from_slice(&x_hat);
    std::fs::write(out.path().join("x_hat.log"), &longer).unwrap();
    std::fs::write(out.path().join("mode.log"), "stale\n".repeat(1000)).unwrap();
    run();
    assert_eq!(std::fs::read(out.path().join("x_hat.log")).unwrap(), x_hat);
    assert_eq!(std::fs::read(out.path().join("mode.log")).unwrap(), mode);
}

#[test]
fn replay_without_recorded_clock_uses_frame_times() {
    // A run folder with only imu_raw.log: times come from the raw frames.
    let run = tempfile::tempdir().unwrap();
    let raw = std::fs::read_to_string(flight_dir().join("imu_raw.log")).unwrap();
    // Convert to \n\r line ends as some of the original's logs have.
    std::fs::write(run.path().join("imu_raw.log"), raw.replace('\n', "\n\r")).unwrap();
    let out = replay_ok(run.path(), &[]);
    let ours = read_table(&out.path().join("kalman_in.log"));
    let raw = read_table(&flight_dir().join("imu_raw.log"));
    assert_eq!(ours.len(), 1120);
    // Row 2 comes from raw row 513: its time and the frame interval since raw row 512.
    assert_eq!(ours[1][0], raw[512][0]);
    assert_eq!(ours[1][1], "0.011383");
    // The measurements do not depend on the clock.
    let theirs = read_table(&flight_dir().join("kalman_in.log"));
    assert_eq!(ours[500][3..], theirs[500][3..]);
}

#[test]
fn replay_refuses_a_short_log_and_a_missing_config() {
    let run = tempfile::tempdir().unwrap();
    let raw = std::fs::read_to_string(flight_dir().join("imu_raw.log")).unwrap();
    let head: String = raw.lines().take(100).map(|l| format!("{l}\n")).collect();
    std::fs::write(run.path().join("imu_raw.log"), head).unwrap();
    let (o, out) = replay_2012(run.path(), &[]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("100 frames are not enough"), "{err}");
    let o = uquad(
        &root(),
        &[
            "replay",
            run.path().to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("config.toml"), "{err}");
}

#[test]
fn replay_names_the_line_of_a_corrupt_record() {
    let run = tempfile::tempdir().unwrap();
    let raw = std::fs::read_to_string(flight_dir().join("imu_raw.log")).unwrap();
    let mut lines: Vec<String> = raw.lines().map(str::to_string).collect();
    lines[599] = lines[599].replacen('\t', "\tnot-a-time", 1);
    std::fs::write(run.path().join("imu_raw.log"), lines.join("\n") + "\n").unwrap();
    let (o, _out) = replay_2012(run.path(), &[]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("imu_raw.log") && err.contains("line 600"),
        "{err}"
    );
}

#[test]
fn replay_refuses_to_write_into_the_folder_it_reads() {
    // A copy of the flight, replayed into itself by another spelling of its path: refused
    // with exit status 2, and its logs untouched.
    let copy = tempfile::tempdir().unwrap();
    for name in ["imu_raw.log", "kalman_in.log", "w.log", "int.log"] {
        std::fs::copy(flight_dir().join(name), copy.path().join(name)).unwrap();
    }
    let before = std::fs::read(copy.path().join("kalman_in.log")).unwrap();
    let same = copy
        .path()
        .join(".")
        .join("..")
        .join(copy.path().file_name().unwrap());
    let o = uquad(
        &root(),
        &[
            "replay",
            copy.path().to_str().unwrap(),
            "--config",
            profile_2012().to_str().unwrap(),
            "--out",
            same.to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("that is the run folder being replayed"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(copy.path().join("kalman_in.log")).unwrap(),
        before
    );
}

/// Several run folders in one command: each into OUT/<its name>, the same bytes as one at a
/// time; a run that fails is named, the others still written, the exit status non-zero.
#[test]
fn many_runs_replay_at_once_each_into_its_folder() {
    let dir = tempfile::tempdir().unwrap();
    let copies: Vec<std::path::PathBuf> = ["a", "b", "c"]
        .iter()
        .map(|n| {
            let to = dir.path().join(n);
            std::fs::create_dir(&to).unwrap();
            for f in std::fs::read_dir(flight_dir()).unwrap() {
                let f = f.unwrap().path();
                std::fs::copy(&f, to.join(f.file_name().unwrap())).unwrap();
            }
            to
        })
        .collect();
    let broken = dir.path().join("broken");
    std::fs::create_dir(&broken).unwrap();
    let out = dir.path().join("out");
    let mut args = vec!["replay"];
    let names: Vec<String> = copies.iter().map(|c| c.display().to_string()).collect();
    args.extend(names.iter().map(String::as_str));
    let broken_s = broken.display().to_string();
    args.push(&broken_s);
    let (profile, out_s) = (profile_2012(), out.display().to_string());
    args.extend(["--config", profile.to_str().unwrap(), "--out", &out_s]);
    let o = uquad(&root(), &args);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "the broken run must fail the batch");
    assert!(
        stdout.contains("replayed 3 of 4 runs") && stdout.contains("3360 Kalman steps"),
        "{stdout}"
    );
    assert!(
        stderr.contains("replay of") && stderr.contains("broken"),
        "{stderr}"
    );
    let single = replay_ok(&copies[0], &[]);
    for n in ["a", "b", "c"] {
        for log in ["x_hat.log", "w.log", "kalman_in.log"] {
            let a = std::fs::read(out.join(n).join(log)).unwrap();
            assert!(
                a == std::fs::read(single.path().join(log)).unwrap(),
                "{n}/{log}"
            );
        }
    }
}

#[test]
fn replay_drops_a_cut_off_last_line_and_says_so() {
    // A run cut off mid-write: the last line of imu_raw.log and of kalman_in.log half there.
    let run = tempfile::tempdir().unwrap();
    for name in ["imu_raw.log", "kalman_in.log", "w.log", "int.log"] {
        let text = std::fs::read_to_string(flight_dir().join(name)).unwrap();
        std::fs::write(run.path().join(name), text).unwrap();
    }
    let cut = |name: &str, keep: &str| {
        let path = run.path().join(name);
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str(keep);
        std::fs::write(path, text).unwrap();
    };
    cut("imu_raw.log", "99.999999\t1327662600.0");
    cut("kalman_in.log", "99.99");
    let (o, out) = replay_2012(run.path(), &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    for name in ["imu_raw.log", "kalman_in.log"] {
        assert!(
            err.lines()
                .any(|l| l.contains("dropped a cut-off last record") && l.contains(name)),
            "no warning for {name}: {err}"
        );
    }
    // The rest replays as the whole flight does.
    assert_eq!(read_table(&out.path().join("kalman_in.log")).len(), 1120);
}
