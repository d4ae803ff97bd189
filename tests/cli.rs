//! The `apfn` command line end to end: `run` and `eval` on small inputs, and clear errors for
//! bad ones (broken RON, unknown systems, impossible configs, wrong flags).

use apfn::cli::{Cli, run};
use clap::Parser;
use std::path::Path;

fn apfn(args: &[&str]) -> anyhow::Result<()> {
    let cli = Cli::try_parse_from(std::iter::once("apfn").chain(args.iter().copied()))?;
    run(cli)
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

const SCHEDULE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/random.ron");

#[test]
fn run_writes_trajectories_and_summary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    apfn(&["run", "--steps", "6", "--out", out.to_str().unwrap()]).unwrap();
    let lines = std::fs::read_to_string(out.join("trajectories.jsonl")).unwrap();
    assert_eq!(lines.lines().count(), 6 * 8, "the default scene has 2 maps × 4 robots");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
    assert!(summary["robot_steps_per_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn eval_writes_the_issue_keys_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let config = write(
        dir.path(),
        "eval.ron",
        &format!(
            "Eval(schedules: [{SCHEDULE:?}], tasks: [tracking, semi_global], \
             maps: [Apartments(split: seen, count: 1), Apartments(split: unseen, count: 1)], \
             episodes: 4, robots_per_map: 2, episode: (steps: 8), seed: 5)"
        ),
    );
    let results = |name: &str| {
        let out = dir.path().join(name);
        apfn(&["eval", "--config", &config, "--out", out.to_str().unwrap()]).unwrap();
        std::fs::read_to_string(out.join("results.json")).unwrap()
    };
    let first = results("a");
    assert_eq!(first, results("b"), "same seed and threads → identical results");
    let rows: Vec<serde_json::Map<String, serde_json::Value>> = serde_json::from_str(&first).unwrap();
    assert_eq!(rows.len(), 4, "2 tasks × 2 splits");
    let keys: Vec<&str> = rows[0].keys().map(String::as_str).collect();
    let mut expected = vec![
        "localizer",
        "policy",
        "task",
        "split",
        "map",
        "particles",
        "episodes",
        "seed",
        "mean_pos_err_m",
        "rmse_pos_m",
        "final_pos_err_m",
        "mean_orient_err_rad",
        "final_orient_err_rad",
        "success_rate",
    ];
    expected.sort_unstable();
    let mut keys = keys;
    keys.sort_unstable();
    assert_eq!(keys, expected, "results.json rows carry exactly the issue's keys");
    assert_eq!(rows[0]["episodes"], 4);
    assert_eq!(rows[2]["task"], "semi_global");
    assert_eq!(rows[2]["particles"], 500, "semi-global default particle count");
    let md = std::fs::read_to_string(dir.path().join("a/results.md")).unwrap();
    assert!(md.contains("| random |") && md.contains("tracking · seen"), "paper-style table:\n{md}");
    let episodes = std::fs::read_to_string(dir.path().join("a/episodes.csv")).unwrap();
    assert_eq!(episodes.lines().count(), 1 + 4 * 4, "a header, then 4 cells × 4 episodes");
    let steps = std::fs::read_to_string(dir.path().join("a/steps.csv")).unwrap();
    assert_eq!(steps.lines().count(), 1 + 4 * 8, "a header, then 4 cells × 8 steps");
    assert!(steps.lines().nth(1).unwrap().contains(",1,4,"), "step 1 of 4 episodes: {steps}");
    let curves = std::fs::read_dir(dir.path().join("a/curves")).unwrap().count();
    assert_eq!(curves, 4, "an error-over-time figure per task and split");
}

#[test]
fn eval_overrides_reach_every_schedule_and_rename_the_localizer() {
    let dir = tempfile::tempdir().unwrap();
    let turn = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/turn.ron");
    let eval = |name: &str, extra: &str| {
        let text = format!(
            "Eval(schedules: [{SCHEDULE:?}, {turn:?}], tasks: [tracking], maps: [Apartments(split: seen, count: 1)], \
             episodes: 2, robots_per_map: 2, episode: (steps: 6), particles: Some(400){extra})"
        );
        let config = write(dir.path(), &format!("{name}.ron"), &text);
        let out = dir.path().join(name);
        apfn(&["eval", "--config", &config, "--out", out.to_str().unwrap()]).unwrap();
        let text = std::fs::read_to_string(out.join("results.json")).unwrap();
        serde_json::from_str::<Vec<serde_json::Value>>(&text).unwrap()
    };
    let plain = eval("plain", "");
    let kld = eval(
        "kld",
        ", localizer: Some(\"amcl\"), \
         overrides: [(\"resample\", (alpha: 1.0, kld: Some((min_particles: 20, max_particles: 400))))]",
    );
    assert_eq!(kld.len(), 2);
    assert!(kld.iter().all(|r| r["localizer"] == "amcl") && plain[0]["localizer"] == "mcl", "{kld:?}");
    assert_eq!(kld[1]["policy"], "turn");
    for (a, b) in plain.iter().zip(&kld) {
        assert_ne!(
            a["mean_pos_err_m"], b["mean_pos_err_m"],
            "the override must change {}'s filter",
            a["policy"]
        );
    }
}

#[test]
fn eval_swaps_replace_a_step_in_every_schedule() {
    let dir = tempfile::tempdir().unwrap();
    let turn = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/turn.ron");
    let text = format!(
        "Eval(schedules: [{SCHEDULE:?}, {turn:?}], tasks: [tracking], maps: [Apartments(split: seen, count: 1)], \
         episodes: 2, robots_per_map: 2, episode: (steps: 4), \
         swaps: [(\"mcl_likelihood_field\", \"mcl_beam_model\", ())])"
    );
    let config = write(dir.path(), "beam.ron", &text);
    let out = dir.path().join("beam");
    apfn(&["eval", "--config", &config, "--out", out.to_str().unwrap()]).unwrap();
    let rows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    let localizers: Vec<_> = rows.iter().map(|r| r["localizer"].as_str().unwrap()).collect();
    assert_eq!(localizers, ["mcl_beam", "mcl_beam"], "both schedules run the swapped-in beam model");
    // Common random numbers: both policies' episodes start alike, so each pairs with the other.
    let paired = std::fs::read_to_string(out.join("paired.md")).unwrap();
    assert!(paired.contains("### mcl_beam · tracking · seen"), "{paired}");
    for (policy, other) in [("random", "turn"), ("turn", "random")] {
        let row = paired
            .lines()
            .find(|l| l.starts_with(&format!("| {policy} |")))
            .unwrap_or_else(|| panic!("{paired}"));
        assert!(row.contains(&format!("| {other} | 2 |")), "both episodes paired: {row}");
    }
}

#[test]
fn eval_inserts_add_a_step_to_every_schedule() {
    let dir = tempfile::tempdir().unwrap();
    let turn = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/turn.ron");
    let config = |inserts: &str| {
        format!(
            "Eval(schedules: [{turn:?}], tasks: [global], maps: [Apartments(split: seen, count: 1)], \
             episodes: 2, robots_per_map: 2, particles: Some(200), episode: (steps: 12), inserts: [{inserts}])"
        )
    };
    let run = |name: &str, inserts: &str| {
        let path = write(dir.path(), &format!("{name}.ron"), &config(inserts));
        let out = dir.path().join(name);
        apfn(&["eval", "--config", &path, "--out", out.to_str().unwrap()]).unwrap();
        std::fs::read_to_string(out.join("episodes.csv")).unwrap()
    };
    let recovery = "(\"mcl_likelihood_field\", \"augmented_recovery\", (alpha_slow: 0.05, alpha_fast: 0.5))";
    let (plain, augmented) = (run("plain", ""), run("augmented", recovery));
    // Common random numbers: the robot drives the same path; only the filter's estimates differ.
    let column = |csv: &str, k: usize| {
        csv.lines().skip(1).map(|l| l.split(',').nth(k).unwrap().to_owned()).collect::<Vec<_>>()
    };
    assert_eq!(column(&plain, 8), column(&augmented, 8), "the same final true poses");
    assert_ne!(column(&plain, 11), column(&augmented, 11), "recovery must change the global estimates");
}

/// A variant evaluates a schedule once more with one step's parameters replaced: its own row,
/// labelled by schedule and variant, whose numbers are those of a schedule file with the change.
#[test]
fn eval_variants_add_a_row_per_schedule_and_variant() {
    let dir = tempfile::tempdir().unwrap();
    let eval = |name: &str, schedules: &str, variants: &str| {
        let text = format!(
            "Eval(schedules: [{schedules}], tasks: [global], maps: [Apartments(split: seen, count: 1)], \
             episodes: 2, robots_per_map: 2, particles: Some(200), episode: (steps: 10), variants: [{variants}])"
        );
        let path = write(dir.path(), &format!("{name}.ron"), &text);
        let out = dir.path().join(name);
        apfn(&["eval", "--config", &path, "--out", out.to_str().unwrap()]).unwrap();
        let json = std::fs::read_to_string(out.join("results.json")).unwrap();
        let rows: Vec<serde_json::Value> = serde_json::from_str(&json).unwrap();
        rows.iter()
            .map(|r| (r["policy"].as_str().unwrap().to_owned(), r["mean_pos_err_m"].as_f64().unwrap()))
            .collect::<Vec<_>>()
    };
    let rows = eval("variants", &format!("{SCHEDULE:?}"), "(\"resample\", \"every_step\", (alpha: 1.0))");
    let policies: Vec<&str> = rows.iter().map(|r| r.0.as_str()).collect();
    assert_eq!(policies, ["random (random)", "random (random+every_step)"]);

    let edited = std::fs::read_to_string(SCHEDULE)
        .unwrap()
        .replace("(\"resample\",             (alpha: 0.5))", "(\"resample\", (alpha: 1.0))");
    let copy = write(dir.path(), "every_step.ron", &edited);
    assert_ne!(
        edited,
        std::fs::read_to_string(SCHEDULE).unwrap(),
        "systems/random.ron resamples at alpha 0.5"
    );
    let alone = eval("copy", &format!("{copy:?}"), "");
    assert_eq!(rows[1].1, alone[0].1, "the variant row is the edited schedule's");
    assert_ne!(rows[0].1, rows[1].1, "resampling at every step changes the estimates");
}

#[test]
fn broken_scene_names_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let scene =
        write(dir.path(), "broken.ron", "Scene(\n  maps: Procedural(split: seen),\n  robots_per_map: -2,\n)");
    let err = apfn(&["run", "--scene", &scene, "--steps", "1"]).unwrap_err().to_string();
    assert!(err.contains("broken.ron:3:"), "error must point at line 3: {err}");
}

#[test]
fn out_of_range_apartment_params_name_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let text =
        "Scene(maps: Procedural(split: seen, count: 1, params: (resolution_m: 2.0)), robots_per_map: 1)";
    let scene = write(dir.path(), "wide.ron", text);
    let err = apfn(&["run", "--scene", &scene, "--steps", "1"]).unwrap_err().to_string();
    assert!(
        err.contains("wide.ron") && err.contains("maps.params.resolution_m") && err.contains("0.005"),
        "{err}"
    );
}

#[test]
fn unknown_system_is_rejected_with_suggestion() {
    let dir = tempfile::tempdir().unwrap();
    let systems = write(dir.path(), "s.ron", "// test\nSchedule(steps: [(\"odometri\", ())])");
    let err = apfn(&["run", "--systems", &systems, "--steps", "1"]).unwrap_err().to_string();
    assert!(err.contains("s.ron:2:") && err.contains("did you mean `odometry`"), "{err}");
}

#[test]
fn bad_eval_configs_fail_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "zero particles",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], particles: Some(0))"
            ),
            "particles",
        ),
        (
            "missing map",
            format!("Eval(schedules: [{SCHEDULE:?}], maps: [Ros(path: \"nowhere.yaml\")])"),
            "nowhere.yaml",
        ),
        (
            "unknown policy file",
            "Eval(schedules: [\"no_such_policy.ron\"], maps: [Apartments(split: seen, count: 1)])".to_owned(),
            "no_such_policy.ron",
        ),
        (
            "override of a step no schedule runs",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 overrides: [(\"depth\", ())])"
            ),
            "overrides[0] (`depth`)",
        ),
        (
            "override out of range",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 overrides: [(\"resample\", (alpha: 3.0))])"
            ),
            "resample.alpha",
        ),
        (
            "swap into another stage",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 swaps: [(\"mcl_likelihood_field\", \"lidar\", ())])"
            ),
            "swaps[0] (`mcl_likelihood_field` → `lidar`)",
        ),
        (
            "swap of a step no schedule runs",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 swaps: [(\"mcl_beam_model\", \"mcl_likelihood_field\", ())])"
            ),
            "no schedule of this config runs `mcl_beam_model`",
        ),
        (
            "insert after a step no schedule runs",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 inserts: [(\"mcl_beam_model\", \"augmented_recovery\", ())])"
            ),
            "inserts[0] (`augmented_recovery` after `mcl_beam_model`)",
        ),
        (
            "variant of a step no schedule runs",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 variants: [(\"sac_policy\", \"step_8000\", ())])"
            ),
            "variants[0] (`step_8000`)`: no schedule of this config runs `sac_policy`",
        ),
        (
            "variant named like a path",
            format!(
                "Eval(schedules: [{SCHEDULE:?}], maps: [Apartments(split: seen, count: 1)], \
                 variants: [(\"resample\", \"../x\", (alpha: 1.0))])"
            ),
            "variants[0] (`../x`)`: expected a name of letters, digits",
        ),
        (
            "no tasks",
            format!("Eval(schedules: [{SCHEDULE:?}], tasks: [], maps: [Apartments(split: seen, count: 1)])"),
            "tasks",
        ),
    ];
    for (what, text, needle) in cases {
        let config = write(dir.path(), "bad.ron", &text);
        let err = apfn(&["eval", "--config", &config, "--out", dir.path().join("out").to_str().unwrap()])
            .expect_err(what)
            .to_string();
        assert!(err.contains(needle), "{what}: error should mention {needle}: {err}");
        assert!(!dir.path().join("out").exists(), "{what}: nothing may be written");
    }
}

#[test]
fn wrong_flag_is_a_usage_error() {
    let err = apfn(&["run", "--stepz", "3"]).unwrap_err().to_string();
    assert!(err.contains("--stepz"), "{err}");
}

/// The worker count is set once per process: asking again for the count it has is fine (a second
/// command run from the library), another count is refused by name.
#[test]
fn threads_are_set_once_per_process() {
    let running = rayon::current_num_threads();
    apfn::cli::set_threads(Some(running)).expect("the count the process already has");
    let err = apfn::cli::set_threads(Some(running + 1)).unwrap_err().to_string();
    assert!(err.contains("--threads") && err.contains(&format!("already runs {running} worker")), "{err}");
}

#[test]
fn pfnet_landscape_runs_on_an_apartment_and_refuses_bad_values_by_flag() {
    let checkpoint = concat!(env!("CARGO_MANIFEST_DIR"), "/models/pfnet_compact.safetensors");
    let base = ["pfnet", "landscape", "--checkpoint", checkpoint, "--apartment", "3", "--poses", "2"];
    apfn(&[&base[..], &["--points", "5"]].concat()).unwrap();
    let even = apfn(&[&base[..], &["--points", "4"]].concat()).unwrap_err().to_string();
    assert_eq!(even, "--points: expected an odd count ≥ 3, found 4");
    let none = apfn(&[&base[..6], &["--poses", "0"]].concat()).unwrap_err().to_string();
    assert!(none.starts_with("--poses"), "{none}");
    let span = apfn(&[&base[..], &["--span-m=-1"]].concat()).unwrap_err().to_string();
    assert_eq!(span, "--span-m: expected more than 0 and at most 10 m, found -1");
    let both = apfn(&[&base[..], &["--map", "m.yaml"]].concat()).unwrap_err().to_string();
    assert!(both.contains("--map") && both.contains("--apartment"), "{both}");
}
