//! `apfn sweep` end to end on a tiny sweep (1 schedule × 1 map group × tracking × 3 seeds): the
//! job list, one job at a time as a cluster array would run them, the merge, skipping finished
//! jobs, and clear errors for a bad index and a missing result.

use apfn::cli::{Cli, run};
use apfn::sweep::{SweepConfig, jobs, list_lines};
use clap::Parser;
use std::path::{Path, PathBuf};

fn apfn(args: &[&str]) -> anyhow::Result<()> {
    let cli = Cli::try_parse_from(std::iter::once("apfn").chain(args.iter().copied()))?;
    run(cli)
}

const SCHEDULE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/random.ron");

/// Writes the tiny sweep into `dir`; its results go to `dir/out`.
fn tiny_sweep(dir: &Path) -> PathBuf {
    let path = dir.join("tiny.ron");
    let text = format!(
        "// tiny: 3 seeds of one cell\nSweep(\n    eval: (schedules: [{SCHEDULE:?}], tasks: [tracking], \
         maps: [Apartments(split: seen, count: 1)], episodes: 2, robots_per_map: 2, \
         episode: (steps: 8)),\n    seeds: [0, 1, 2],\n    out: \"out\",\n)\n"
    );
    std::fs::write(&path, text).expect("write the sweep file");
    path
}

const NAMES: [&str; 3] =
    ["random__tracking__seen__seed0", "random__tracking__seen__seed1", "random__tracking__seen__seed2"];

#[test]
fn sweep_runs_job_by_job_then_merges_and_skips_finished_jobs() {
    let dir = tempfile::tempdir().unwrap();
    let file = tiny_sweep(dir.path());
    let f = file.to_str().unwrap();
    let jobs_dir = dir.path().join("out/jobs");

    // The listing `--list-jobs` prints.
    let sweep = SweepConfig::load(&file).expect("the tiny sweep is valid");
    let lines = list_lines(&jobs(&sweep).unwrap());
    let expected: Vec<String> = NAMES.iter().enumerate().map(|(i, n)| format!("{i}\t{n}")).collect();
    assert_eq!(lines, expected, "one `index<TAB>name` line per seed, in seed order");
    apfn(&["sweep", f, "--list-jobs"]).expect("--list-jobs succeeds");
    assert!(!dir.path().join("out").exists(), "--list-jobs must not write anything");

    // One job at a time, as a Slurm array or GNU parallel would run them.
    for (i, name) in NAMES.iter().enumerate() {
        apfn(&["sweep", f, "--job", &i.to_string()]).unwrap_or_else(|e| panic!("--job {i}: {e:#}"));
        let path = jobs_dir.join(format!("{}.json", name));
        let job: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("--job {i} must write {path:?}: {e}")),
        )
        .unwrap();
        assert_eq!(job["row"]["seed"], i as u64, "job {i} runs seed {i}");
        assert_eq!(job["row"]["episodes"], 2);
        assert!(job["wall_s"].as_f64().unwrap() > 0.0, "job {i} records its wall-clock time");
    }
    let seed_rows: Vec<serde_json::Value> = NAMES
        .iter()
        .map(|n| {
            serde_json::from_str(&std::fs::read_to_string(jobs_dir.join(format!("{n}.json"))).unwrap())
                .unwrap()
        })
        .collect();
    assert_ne!(
        seed_rows[0]["row"]["mean_pos_err_m"], seed_rows[1]["row"]["mean_pos_err_m"],
        "different seeds must give different episodes"
    );

    // Merge: one row with n = 3 and a finite interval.
    apfn(&["sweep", f, "--merge"]).expect("--merge with all jobs done");
    let merged: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/sweep.json")).unwrap()).unwrap();
    assert_eq!(merged.len(), 1, "one cell across three seeds: {merged:?}");
    let row = &merged[0];
    assert_eq!((row["n"].as_u64(), row["schedule"].as_str()), (Some(3), Some("random")));
    let mean = row["mean_pos_err_m"]["mean"].as_f64().expect("a mean");
    let ci = row["mean_pos_err_m"]["ci95"].as_f64().expect("three seeds give a CI");
    assert!(mean.is_finite() && ci.is_finite() && ci > 0.0, "mean {mean}, ci {ci}");
    let seeds_mean =
        seed_rows.iter().map(|r| r["row"]["mean_pos_err_m"].as_f64().unwrap()).sum::<f64>() / 3.0;
    assert!((mean - seeds_mean).abs() < 1e-6, "merged mean {mean} is the seeds' mean {seeds_mean}");
    let csv = std::fs::read_to_string(dir.path().join("out/sweep.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains("mean_pos_err_m_ci95"), "csv header:\n{csv}");
    let md = std::fs::read_to_string(dir.path().join("out/sweep.md")).unwrap();
    assert!(md.contains("| random | mcl | random | tracking | seen | 3 |") && md.contains(" ± "), "{md}");

    // A plain rerun skips all three (their files stay untouched) and merges again.
    let stamp = |n: &str| std::fs::metadata(jobs_dir.join(format!("{n}.json"))).unwrap().modified().unwrap();
    let before: Vec<_> = NAMES.iter().map(|n| stamp(n)).collect();
    apfn(&["sweep", f]).expect("a rerun of a finished sweep");
    let after: Vec<_> = NAMES.iter().map(|n| stamp(n)).collect();
    assert_eq!(before, after, "a rerun must not redo finished jobs");

    // Out of range.
    let err = apfn(&["sweep", f, "--job", "7"]).expect_err("there are only 3 jobs").to_string();
    assert!(err.contains("job 7") && err.contains("below 3"), "{err}");

    // A missing result is named, unless --allow-partial.
    std::fs::remove_file(jobs_dir.join(format!("{}.json", NAMES[1]))).unwrap();
    let err = apfn(&["sweep", f, "--merge"]).expect_err("a job result is missing").to_string();
    assert!(err.contains(NAMES[1]) && !err.contains(NAMES[0]), "must name exactly the missing job: {err}");
    apfn(&["sweep", f, "--merge", "--allow-partial"]).expect("partial merge");
    let merged: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/sweep.json")).unwrap()).unwrap();
    assert_eq!(merged[0]["n"], 2, "partial merge of the two remaining seeds");
}

#[test]
fn whole_sweep_matches_job_by_job_and_reruns_stale_jobs() {
    let dir = tempfile::tempdir().unwrap();
    let file = tiny_sweep(dir.path());
    let f = file.to_str().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    apfn(&["sweep", f, "--out", a.to_str().unwrap()]).expect("whole sweep");
    for i in 0..3 {
        apfn(&["sweep", f, "--job", &i.to_string(), "--out", b.to_str().unwrap()]).expect("one job");
    }
    let row = |out: &Path, name: &str| {
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("jobs").join(format!("{name}.json"))).unwrap(),
        )
        .unwrap();
        v["row"].clone()
    };
    for name in NAMES {
        assert_eq!(row(&a, name), row(&b, name), "{name}: the parallel run and --job give the same numbers");
    }

    // Changing what the jobs depend on (episode length, a step override, an inserted step)
    // makes their results stale: merge refuses them.
    let original = std::fs::read_to_string(&file).unwrap();
    for changed in [
        original.replace("steps: 8", "steps: 9"),
        original.replace("steps: 8)", "steps: 8), overrides: [(\"resample\", (alpha: 1.0))]"),
        original.replace(
            "steps: 8)",
            "steps: 8), inserts: [(\"mcl_likelihood_field\", \"augmented_recovery\", ())]",
        ),
    ] {
        assert_ne!(changed, original);
        std::fs::write(&file, changed).unwrap();
        let err =
            apfn(&["sweep", f, "--merge", "--out", a.to_str().unwrap()]).expect_err("stale").to_string();
        assert!(err.contains("stale") && err.contains(NAMES[2]), "{err}");
    }
}

#[test]
fn bad_sweep_files_fail_before_any_job() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("no seeds", format!("Sweep(eval: (schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)]), seeds: [], out: \"o\")"), "seeds"),
        ("duplicate seed", format!("Sweep(eval: (schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)]), seeds: [1, 1], out: \"o\")"), "listed twice"),
        ("unknown schedule", "Sweep(eval: (schedules: [\"nope.ron\"], maps: [Apartments(split: seen, count: 1)]), seeds: [0], out: \"o\")".to_owned(), "nope.ron"),
        ("colliding names", format!("Sweep(eval: (schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1), Apartments(split: seen, first: 1, count: 1)]), seeds: [0], out: \"o\")"), "would both be named"),
        ("typo", format!("Sweep(eval: (schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)]),\n seedz: [0], out: \"o\")"), "bad.ron:2:"),
    ];
    for (what, text, needle) in cases {
        let path = dir.path().join("bad.ron");
        std::fs::write(&path, text).unwrap();
        let err = apfn(&["sweep", path.to_str().unwrap(), "--list-jobs"]).expect_err(what);
        let msg = format!("{err:#}");
        assert!(msg.contains(needle), "{what}: expected `{needle}` in: {msg}");
    }
    assert!(!dir.path().join("o").exists(), "no job may run for a bad sweep file");
}
