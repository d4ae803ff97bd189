//! The same seed gives the same table at any thread count: every parallel loop draws from
//! streams keyed by fixed chunks, never by thread.

use apfn::eval::{EvalConfig, ResultRow, cells, run_cell};
use std::path::Path;

fn table(threads: usize) -> Vec<ResultRow> {
    let schedules =
        ["random.ron", "goalnav.ron"].map(|s| format!("{}/systems/{s}", env!("CARGO_MANIFEST_DIR")));
    let config: EvalConfig = ron::from_str(&format!(
        "Eval(schedules: {schedules:?}, tasks: [tracking, global], maps: [Apartments(split: unseen, count: 2)], \
         episodes: 4, robots_per_map: 2, episode: (steps: 10), seed: 3)"
    ))
    .expect("valid config");
    let eval = config.into_loaded(Path::new("tests/determinism")).expect("loads");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| cells(&eval).iter().map(|c| run_cell(&eval, c, || ()).expect("cell runs").row).collect())
}

#[test]
fn eval_table_is_identical_at_one_and_three_threads() {
    let (one, three) = (table(1), table(3));
    assert_eq!(one.len(), 4, "2 schedules × 2 tasks × 1 split");
    assert_eq!(one, three, "thread count must not change any number");
}
