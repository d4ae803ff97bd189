//! Offline replay end to end: `record` a procedural apartment, export its map as ROS YAML + PGM,
//! `localize` the log with the classical filter; plus the log format's errors and the CLI.

use apfn::cli::record::{Recording, export_map, record};
use apfn::cli::run::load_pipeline;
use apfn::cli::{Cli, run};
use apfn::compose::{LoadedScene, MapSource, Scene};
use apfn::particles::Task;
use apfn::replay::{
    EstimateLine, InitialGuess, Localizer, LocalizerParams, LogLine, MIN_FIT, SHIPPED_PFNET, read_log,
    scan_fit, to_jsonl,
};
use apfn::world::map::procedural::{Split, generate_apartment};
use apfn::world::map::{DistanceField, load_ros_map};
use apfn::world::{OccupancyMap, Pose2, angle_error};
use clap::Parser;
use std::path::{Path, PathBuf};

/// One seen apartment with one robot, the embedded random-policy schedule.
const SCENE_RON: &str =
    "Scene(maps: Procedural(split: seen, first: 0, count: 1), robots_per_map: 1, seed: 11)";

fn small_scene() -> LoadedScene {
    let scene = Scene {
        maps: MapSource::Procedural { split: Split::Seen, first: 0, count: 1, params: Default::default() },
        robots_per_map: 1,
        robots_collide: false,
        seed: 11,
        episode: Default::default(),
        robot: Default::default(),
        physics: Default::default(),
        systems: None,
    };
    scene.into_loaded(Path::new("tests/replay_scene.ron")).expect("the small scene loads")
}

fn record_small(steps: u64) -> Recording {
    let scene = small_scene();
    let pipeline = load_pipeline(None, &scene).expect("the embedded schedule loads");
    record(scene, pipeline, steps, 0, || {}).expect("recording runs")
}

fn tracking(particles: Option<usize>) -> LocalizerParams {
    let mut params = LocalizerParams::default();
    params.init.task = Task::Tracking;
    params.init.particles = particles;
    params
}

/// Exports the recording's map, reloads it from disk and localizes the log on it.
fn localize(recording: &Recording, dir: &Path, seed: u64) -> Vec<EstimateLine> {
    let yaml = export_map(recording, dir).expect("map exports");
    let map = load_ros_map(&yaml).expect("exported map loads back");
    let truth = recording.lines[0].truth_pose().expect("recorded lines carry truth");
    let mut filter = Localizer::new(map, tracking(None), InitialGuess::PerturbedTruth(truth), seed)
        .expect("filter starts");
    filter.replay(&recording.lines, || {})
}

fn position_errors(lines: &[LogLine], estimates: &[EstimateLine]) -> Vec<f32> {
    lines
        .iter()
        .zip(estimates)
        .map(|(l, e)| {
            let truth = l.truth_pose().expect("truth");
            truth.distance(&Pose2::new(e.pose[0], e.pose[1], e.pose[2]))
        })
        .collect()
}

fn parse(args: &[&str]) -> Cli {
    Cli::try_parse_from(args).unwrap_or_else(|e| panic!("{args:?} should parse: {e}"))
}

fn s(path: &Path) -> &str {
    path.to_str().expect("temp paths are UTF-8")
}

#[test]
fn replay_record_writes_cumulative_odometry_and_scan_time_truth() {
    let rec = record_small(60);
    assert_eq!(rec.lines.len(), 60, "one line per step");
    assert_eq!(rec.lines[0].odom, [0.0, 0.0, 0.0], "odom starts at the origin, as ROS odom does");
    assert_eq!(rec.map_name, "apartment_0");
    let scan = &rec.lines[0];
    assert_eq!(scan.ranges.len(), 228, "the paper's LiDAR: 228 rays");
    assert!((scan.range_max - 5.6).abs() < 1e-6 && (scan.angle_min + 120f32.to_radians()).abs() < 1e-5);
    let mut moved = 0.0;
    for pair in rec.lines.windows(2) {
        assert!(
            (pair[1].t - pair[0].t - 0.6).abs() < 1e-6,
            "t advances 0.6 s per step: {} → {}",
            pair[0].t,
            pair[1].t
        );
        let odom = pair[0].odom_pose().between(&pair[1].odom_pose());
        let (a, b) = (pair[0].truth_pose().expect("truth"), pair[1].truth_pose().expect("truth"));
        let true_delta = a.between(&b);
        let gap = (odom.x - true_delta.x).hypot(odom.y - true_delta.y);
        assert!(
            gap < 0.06,
            "odometry deltas follow the true motion up to 0.01 m noise: gap {gap} m at t {}",
            pair[1].t
        );
        assert!(angle_error(odom.yaw, true_delta.yaw) < 0.35, "yaw noise is 5° per step");
        moved += a.distance(&b);
    }
    assert!(moved > 1.0, "the random policy moves the robot: {moved} m in 60 steps");
}

#[test]
fn replay_tracking_localizes_a_recorded_log() {
    let rec = record_small(60);
    let dir = tempfile::tempdir().expect("tempdir");
    let reloaded = load_ros_map(&export_map(&rec, dir.path()).expect("export")).expect("reload");
    assert_eq!(reloaded.cells, rec.map.cells, "the exported map is the map the robot drove on");
    let estimates = localize(&rec, dir.path(), 5);
    assert_eq!(estimates.len(), rec.lines.len(), "one estimate per line");
    let errors = position_errors(&rec.lines, &estimates);
    let last = *errors.last().expect("errors");
    let half = &errors[errors.len() / 2..];
    let mean_last_half = half.iter().sum::<f32>() / half.len() as f32;
    assert!(last < 0.3, "final position error {last} m, expected < 0.3 m; errors {errors:?}");
    assert!(mean_last_half < 0.3, "mean error over the last half {mean_last_half} m, expected < 0.3 m");
    assert!(estimates.iter().all(|e| e.cov.iter().all(|c| c.is_finite())), "covariances are finite");
    assert!(estimates[59].cov[0] >= 0.0 && estimates[59].cov[4] >= 0.0, "variances are non-negative");
}

#[test]
fn replay_scans_fit_their_own_map_at_the_estimates_and_not_another() {
    let rec = record_small(40);
    let dir = tempfile::tempdir().expect("tempdir");
    let estimates = localize(&rec, dir.path(), 3);
    let mean_fit = |map: &OccupancyMap| {
        let field = DistanceField::build(map);
        let fits: Vec<f32> = rec
            .lines
            .iter()
            .zip(&estimates)
            .filter_map(|(l, e)| {
                scan_fit(&l.scan(), &Pose2::new(e.pose[0], e.pose[1], e.pose[2]), map, &field)
            })
            .collect();
        fits.iter().sum::<f32>() / fits.len() as f32
    };
    let own = mean_fit(&rec.map);
    assert!(own >= MIN_FIT, "a tracked log fits its own map: {own}");
    let other = mean_fit(&generate_apartment(Split::Seen.seeds().start + 7, &Default::default()));
    assert!(other < MIN_FIT, "the same scans and poses do not fit another apartment: {other}");
}

#[test]
fn replay_same_seed_gives_same_poses() {
    let rec = record_small(30);
    let dir = tempfile::tempdir().expect("tempdir");
    let poses = |seed| localize(&rec, dir.path(), seed).into_iter().map(|e| e.pose).collect::<Vec<_>>();
    let (a, b, c) = (poses(3), poses(3), poses(4));
    assert_eq!(a, b, "same seed, same log → identical poses");
    assert_ne!(a, c, "another seed draws other particles");
}

#[test]
fn replay_skips_nan_beams() {
    let mut rec = record_small(60);
    for line in rec.lines.iter_mut() {
        line.ranges.iter_mut().step_by(2).for_each(|r| *r = f32::NAN);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("nan.jsonl");
    std::fs::write(&log, to_jsonl(&rec.lines).expect("serialise")).expect("write log");
    let text = std::fs::read_to_string(&log).expect("read log");
    assert!(text.contains("null"), "NaN ranges are written as null");
    let lines = read_log(&log).expect("null ranges load as NaN");
    assert!(lines[0].ranges[0].is_nan());
    let estimates = localize(&Recording { lines, ..rec.clone() }, dir.path(), 5);
    let errors = position_errors(&rec.lines, &estimates);
    let last = *errors.last().expect("errors");
    assert!(last.is_finite() && last < 0.3, "half the beams NaN: final error {last} m, expected < 0.3 m");
}

#[test]
fn replay_malformed_line_names_its_number_and_field() {
    let rec = record_small(5);
    let dir = tempfile::tempdir().expect("tempdir");
    let mut text: Vec<String> =
        rec.lines.iter().map(|l| serde_json::to_string(l).expect("serialise")).collect();
    text[2] = text[2].replacen("\"odom\":[", "\"odom\":[\"east\",", 1);
    let log = dir.path().join("bad.jsonl");
    std::fs::write(&log, text.join("\n")).expect("write log");
    let err = read_log(&log).expect_err("line 3 is malformed").to_string();
    assert!(
        err.contains("bad.jsonl:3:") && err.contains("`odom`"),
        "error must name line 3 and `odom`: {err}"
    );

    text[2] = "{\"t\": 1.2, \"odom\": [0, 0".into();
    std::fs::write(&log, text.join("\n")).expect("write log");
    let err = read_log(&log).expect_err("line 3 is cut short").to_string();
    assert!(err.contains("bad.jsonl:3:"), "syntax errors name the line: {err}");
}

#[test]
fn replay_cli_record_then_localize() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = dir.path().join("scene.ron");
    std::fs::write(&scene, SCENE_RON).expect("write scene");
    let (log, maps, est) =
        (dir.path().join("run.jsonl"), dir.path().join("maps"), dir.path().join("est.jsonl"));
    let args =
        ["apfn", "record", "--scene", s(&scene), "--steps", "40", "--out", s(&log), "--export-map", s(&maps)];
    run(parse(&args)).expect("apfn record runs");
    let yaml: PathBuf = maps.join("apartment_0.yaml");
    assert!(yaml.is_file() && maps.join("apartment_0.pgm").is_file(), "--export-map writes YAML + PGM");

    let localize = ["apfn", "localize", "--map", s(&yaml), "--log", s(&log), "--seed", "2", "--out", s(&est)];
    run(parse(&localize)).expect("apfn localize runs");
    let lines = read_log(&log).expect("the recorded log reads back");
    let estimates: Vec<EstimateLine> = std::fs::read_to_string(&est)
        .expect("EST written")
        .lines()
        .map(|l| serde_json::from_str(l).expect("each EST line is {t, pose, cov, update_ms}"))
        .collect();
    assert_eq!(estimates.len(), 40, "one estimate per log line");
    assert!(lines.iter().zip(&estimates).all(|(l, e)| l.t == e.t), "estimates carry the log's t");
    let errors = position_errors(&lines, &estimates);
    assert!(errors[39] < 0.3, "CLI tracking run ends within 0.3 m: {errors:?}");

    // --init as given (the true start, so no task perturbation) gives another, valid start.
    let first = lines[0].truth.expect("truth");
    let init = format!("{},{},{}", first[0], first[1], first[2]);
    let with_init = [&localize[..], &["--init", &init, "--particles", "100"]].concat();
    run(parse(&with_init)).expect("--init x,y,θ runs");

    // nav2-style KLD-sampling: the filter still tracks.
    run(parse(&[&localize[..], &["--kld", "200,1000"]].concat())).expect("--kld MIN,MAX runs");
    let text = std::fs::read_to_string(&est).expect("EST rewritten");
    let estimates: Vec<EstimateLine> = text.lines().map(|l| serde_json::from_str(l).expect("line")).collect();
    let errors = position_errors(&lines, &estimates);
    assert!(errors[39] < 0.3, "KLD tracking run ends within 0.3 m: {errors:?}");
}

#[test]
fn replay_pfnet_tracks_a_recorded_log_through_the_same_systems() {
    let shipped = Path::new(SHIPPED_PFNET);
    if !shipped.is_file() {
        return eprintln!("skipped: {} is absent (run from the repository's root)", shipped.display());
    }
    let rec = record_small(40);
    let dir = tempfile::tempdir().expect("tempdir");
    let (log, est) = (dir.path().join("run.jsonl"), dir.path().join("est.jsonl"));
    std::fs::write(&log, to_jsonl(&rec.lines).expect("serialise")).expect("write log");
    let yaml = export_map(&rec, dir.path()).expect("export");
    let base = ["apfn", "localize", "--map", s(&yaml), "--log", s(&log), "--seed", "2", "--out", s(&est)];
    run(parse(&[&base[..], &["--localizer", "pfnet"]].concat())).expect("localize --localizer pfnet runs");
    let estimates: Vec<EstimateLine> = std::fs::read_to_string(&est)
        .expect("EST written")
        .lines()
        .map(|l| serde_json::from_str(l).expect("each EST line parses"))
        .collect();
    assert_eq!(estimates.len(), rec.lines.len(), "one estimate per log line");
    let errors = position_errors(&rec.lines, &estimates);
    let half = &errors[errors.len() / 2..];
    let mean = half.iter().sum::<f32>() / half.len() as f32;
    // The compact PF-net tracks apartments to ~30 cm (docs/results/passive.md); the start alone is
    // 0.3 m off per axis, and a filter that ignored its scans would drift with the odometry.
    assert!(mean < 0.45, "PF-net tracking: mean error over the last half {mean} m; errors {errors:?}");

    let cached = [&base[..], &["--localizer", "pfnet", "--features", "cached"]].concat();
    run(parse(&cached)).expect("localize --localizer pfnet --features cached runs");

    // The scan-laid wide-view checkpoint gets the grids it reads and its sharper likelihood.
    let scan_wide = "pfnet:models/pfnet_compact_scan_wide.safetensors";
    let sharp = [&base[..], &["--localizer", scan_wide, "--converged-scale", "0.5,10"]].concat();
    run(parse(&sharp)).expect("localize with the scan-laid checkpoint, sharpened once converged, runs");
    let estimates: Vec<EstimateLine> = std::fs::read_to_string(&est)
        .expect("EST rewritten")
        .lines()
        .map(|l| serde_json::from_str(l).expect("each EST line parses"))
        .collect();
    let errors = position_errors(&rec.lines, &estimates);
    let mean = errors[errors.len() / 2..].iter().sum::<f32>() / (errors.len() - errors.len() / 2) as f32;
    assert!(
        mean < 0.2,
        "scan-laid PF-net tracking: mean error over the last half {mean} m; errors {errors:?}"
    );

    let missing = dir.path().join("nowhere.safetensors");
    let flag = format!("pfnet:{}", missing.display());
    let err =
        format!("{:#}", run(parse(&[&base[..], &["--localizer", &flag]].concat())).expect_err("no file"));
    assert!(err.contains("nowhere.safetensors"), "the missing checkpoint is named: {err}");
    let err = Cli::try_parse_from([&base[..], &["--localizer", "beam:x.safetensors"]].concat())
        .expect_err("beam takes no checkpoint")
        .to_string();
    assert!(err.contains("only pfnet"), "a checkpoint on a classical model is refused: {err}");
}

#[test]
fn replay_cli_rejects_bad_inputs_before_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = record_small(3);
    let log = dir.path().join("ok.jsonl");
    std::fs::write(&log, to_jsonl(&rec.lines).expect("serialise")).expect("write log");
    let yaml = export_map(&rec, dir.path()).expect("export");
    let out = dir.path().join("never.jsonl");
    let base = ["apfn", "localize", "--map", s(&yaml), "--log", s(&log), "--out", s(&out)];
    let fails = |extra: &[&str]| -> String {
        let args = [&base[..], extra].concat();
        match run(parse(&args)) {
            Ok(()) => panic!("{extra:?} must fail"),
            Err(e) => format!("{e:#}"),
        }
    };

    let err = fails(&["--particles", "0"]);
    assert!(err.contains("--particles 0"), "zero particles named: {err}");
    let err = fails(&["--localizer", "pfnet", "--likelihood-scale", "0"]);
    assert!(err.contains("--likelihood-scale 0") && err.contains("> 0"), "a zero scale named: {err}");
    let err = fails(&["--likelihood-scale", "10"]);
    assert!(err.contains("--localizer pfnet"), "a scale on the likelihood field is refused: {err}");
    let err =
        Cli::try_parse_from([&base[..], &["--converged-scale", "0.5"]].concat()).expect_err("one value");
    assert!(err.to_string().contains("SPREAD,SCALE"), "--converged-scale format named: {err}");
    let err = fails(&["--kld", "900,100"]);
    assert!(err.contains("--kld") && err.contains("MIN ≤ MAX"), "inverted --kld named: {err}");
    let err =
        Cli::try_parse_from([&base[..], &["--kld", "500"]].concat()).expect_err("one value").to_string();
    assert!(err.contains("MIN,MAX"), "--kld format named: {err}");
    let err =
        Cli::try_parse_from([&base[..], &["--init", "1,2"]].concat()).expect_err("2 values").to_string();
    assert!(err.contains("--init") && err.contains("found 2"), "wrong --init count named: {err}");
    let err = Cli::try_parse_from([&base[..], &["--task", "kidnapped"]].concat()).expect_err("bad task");
    assert!(err.to_string().contains("semi_global"), "known tasks listed: {err}");

    let missing = dir.path().join("missing.yaml");
    let args = ["apfn", "localize", "--map", s(&missing), "--log", s(&log), "--out", s(&out)];
    let err = format!("{:#}", run(parse(&args)).expect_err("missing map"));
    assert!(err.contains("missing.yaml"), "the missing map is named: {err}");

    let no_truth: Vec<LogLine> = rec.lines.iter().map(|l| LogLine { truth: None, ..l.clone() }).collect();
    std::fs::write(&log, to_jsonl(&no_truth).expect("serialise")).expect("write log");
    let err = format!("{:#}", run(parse(&base)).expect_err("tracking without a start"));
    assert!(err.contains("--init"), "a tracking run without truth or --init asks for --init: {err}");
    assert!(!out.exists(), "nothing is written when the inputs are rejected");

    let args = ["apfn", "record", "--steps", "2", "--robot", "99", "--out", s(&out)];
    let err = run(parse(&args)).expect_err("robot out of range").to_string();
    assert!(err.contains("--robot 99") && err.contains("8 robots"), "robot count named: {err}");
    let schedule = dir.path().join("blind.ron");
    std::fs::write(
        &schedule,
        "Schedule(steps: [(\"odometry\", ()), (\"random_policy\", ()), (\"drive\", ()), (\"physics\", ())])",
    )
    .expect("write schedule");
    let args = ["apfn", "record", "--systems", s(&schedule), "--steps", "2", "--out", s(&out)];
    let err = run(parse(&args)).expect_err("no lidar").to_string();
    assert!(err.contains("blind.ron") && err.contains("`lidar`"), "the missing step is named: {err}");
}
