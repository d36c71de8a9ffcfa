//! The whole closed-loop replay of the 2012-05-25 flight (read logs, 1120 steps of
//! measurement → EKF → controller, write the four logs), in process.

use criterion::{Criterion, criterion_group, criterion_main};
use std::path::Path;

fn bench_replay(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let profile = uquad::config::load(&root.join("config/flight-2012-05.toml"), &[])
        .expect("the 2012 profile loads");
    let run = root.join("tests/data/flight-2012-05-25");
    let out = std::env::temp_dir().join(format!("uquad-bench-replay-{}", std::process::id()));
    c.bench_function("replay_flight_2012_05_25", |b| {
        b.iter(|| {
            let s = uquad::app::replay::run(&run, &profile, &out).expect("replay runs");
            assert_eq!(s.kalman_steps, 1120);
        })
    });
    let _ = std::fs::remove_dir_all(&out);
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench_replay
}
criterion_main!(benches);
