//! `apfn localize --bag`: a synthetic drive around a small room, written as a rosbag2 MCAP file
//! (CDR LaserScan + Odometry at their own rates), localized through the CLI, compared with the
//! truth and with the same data as a JSON Lines log; plus the reader's errors and its behaviour
//! on damaged files.

use apfn::cli::{Cli, run};
use apfn::replay::bag::{
    BagLog, BagTopics, BagWriter, Header, ODOM_FRAME, OdometryMsg, log_to_bag, parse_bag, scan_message,
};
use apfn::replay::{EstimateLine, LogLine, to_jsonl};
use apfn::sense::{LidarParams, LidarScan, RayGrid, cast_scan};
use apfn::world::map::save_ros_map;
use apfn::world::{Cell, OccupancyMap, Pose2};
use clap::Parser;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};

/// ROS time of the first scan: a real epoch stamp, so seconds and nanoseconds both matter.
const T0: f64 = 1_700_000_000.0;
const SCAN_PERIOD_S: f64 = 0.1;
const SCANS: usize = 150;

/// A 5 m × 4 m room at 5 cm: walls, a pillar in the middle, a shelf and a box (no symmetry).
fn room() -> OccupancyMap {
    let (w, h) = (100, 80);
    let mut map = OccupancyMap::filled(w, h, 0.05, Cell::Free);
    let mut fill = |x0: f32, y0: f32, x1: f32, y1: f32| {
        for j in (y0 / 0.05) as usize..(y1 / 0.05) as usize {
            for i in (x0 / 0.05) as usize..(x1 / 0.05) as usize {
                map.set(i, j, Cell::Occupied);
            }
        }
    };
    fill(0.0, 0.0, 5.0, 0.05);
    fill(0.0, 3.95, 5.0, 4.0);
    fill(0.0, 0.0, 0.05, 4.0);
    fill(4.95, 0.0, 5.0, 4.0);
    fill(2.3, 1.8, 2.7, 2.2);
    fill(0.5, 0.05, 1.5, 0.25);
    fill(4.15, 3.25, 4.45, 3.55);
    map
}

/// The true pose `tau` seconds after the first scan: an ellipse around the pillar at ≈ 0.4 m/s,
/// facing along the path.
fn truth_at(tau: f64) -> Pose2 {
    let phi = TAU * tau / 20.0;
    let (a, b) = (1.5, 1.0);
    let heading = (b * phi.cos()).atan2(-a * phi.sin());
    Pose2::new((2.5 + a * phi.cos()) as f32, (2.0 + b * phi.sin()) as f32, heading as f32)
}

/// Odometry: the true motion since the first scan, in an odom frame that starts at the origin.
fn odom_at(tau: f64) -> Pose2 {
    truth_at(0.0).between(&truth_at(tau))
}

/// A ROS driver's scan at `pose` with a 3.5 m LiDAR (TurtleBot3's): misses as +∞ (REP 117),
/// every 17th beam NaN.
fn ros_scan(grid: &RayGrid, pose: Pose2) -> LidarScan {
    let mut scan = LidarScan::default();
    let params = LidarParams { range_max_m: 3.5, ..Default::default() };
    cast_scan(grid, pose, &[], &params, &mut scan);
    for (i, r) in scan.ranges_m.iter_mut().enumerate() {
        if *r >= params.range_max_m {
            *r = f32::INFINITY;
        } else if i % 17 == 0 {
            *r = f32::NAN;
        }
    }
    scan
}

/// The drive as log lines (t = the scan's stamp as a bag stores it, odometry at that stamp).
fn drive(map: &OccupancyMap) -> Vec<LogLine> {
    let grid = RayGrid::from_map(map);
    (0..SCANS)
        .map(|k| {
            let tau = k as f64 * SCAN_PERIOD_S;
            let t = Header::at(T0 + tau, "").stamp_s();
            LogLine::new(t, odom_at(tau), &ros_scan(&grid, truth_at(tau)), Some(truth_at(tau)))
        })
        .collect()
}

/// A bag with the scans of `lines` and odometry at `odom_taus` (seconds after the first scan).
fn bag_with_odometry(lines: &[LogLine], odom_taus: impl Iterator<Item = f64>) -> Vec<u8> {
    let mut bag = BagWriter::new(true).expect("writer");
    let scans = bag.add_scan_topic("/scan").expect("scan topic");
    let odom = bag.add_odometry_topic("/odom").expect("odom topic");
    let mut odom_taus = odom_taus.peekable();
    for line in lines {
        // Messages in receive order: odometry up to the scan's stamp, then the scan.
        while let Some(tau) = odom_taus.next_if(|&tau| T0 + tau <= line.t) {
            let msg = OdometryMsg::planar(Header::at(T0 + tau, ODOM_FRAME), "base_footprint", odom_at(tau));
            bag.write(odom, T0 + tau, &msg.encode(true)).expect("odometry written");
        }
        bag.write(scans, line.t, &scan_message(line).encode(true)).expect("scan written");
    }
    for tau in odom_taus {
        let msg = OdometryMsg::planar(Header::at(T0 + tau, ODOM_FRAME), "base_footprint", odom_at(tau));
        bag.write(odom, T0 + tau, &msg.encode(true)).expect("odometry written");
    }
    bag.finish().expect("bag finished")
}

/// Odometry at 30 Hz, half a period out of step with the scans, covering the whole drive.
fn odometry_30hz() -> impl Iterator<Item = f64> {
    (0..=(SCANS as i64 * 3 + 2)).map(|k| (k as f64 - 0.5) / 30.0)
}

fn parse(args: &[&str]) -> Cli {
    Cli::try_parse_from(args).unwrap_or_else(|e| panic!("{args:?} should parse: {e}"))
}

fn s(path: &Path) -> &str {
    path.to_str().expect("temp paths are UTF-8")
}

fn read_estimates(path: &Path) -> Vec<EstimateLine> {
    std::fs::read_to_string(path)
        .expect("estimates written")
        .lines()
        .map(|l| serde_json::from_str(l).expect("{t, pose, cov, update_ms}"))
        .collect()
}

struct Files {
    _dir: tempfile::TempDir,
    yaml: PathBuf,
    bag: PathBuf,
    dir: PathBuf,
}

fn files(bag: &[u8]) -> Files {
    let dir = tempfile::tempdir().expect("tempdir");
    let yaml = dir.path().join("room.yaml");
    save_ros_map(&room(), &yaml).expect("map saved");
    let bag_path = dir.path().join("drive.mcap");
    std::fs::write(&bag_path, bag).expect("bag written");
    Files { dir: dir.path().into(), _dir: dir, yaml, bag: bag_path }
}

/// `--init` at the true start pose.
fn init_arg() -> String {
    let p = truth_at(0.0);
    format!("{},{},{}", p.x, p.y, p.yaw)
}

fn localize_bag(f: &Files, out: &Path) {
    let init = init_arg();
    let args = ["apfn", "localize", "--map", s(&f.yaml), "--bag", s(&f.bag), "--init", &init];
    run(parse(&[&args[..], &["--seed", "4", "--out", s(out)]].concat())).expect("localize --bag runs");
}

#[test]
fn bag_localize_tracks_a_synthetic_drive() {
    let lines = drive(&room());
    let f = files(&bag_with_odometry(&lines, odometry_30hz()));
    let out = f.dir.join("est.jsonl");
    localize_bag(&f, &out);
    let estimates = read_estimates(&out);
    assert_eq!(estimates.len(), SCANS, "one estimate per scan");
    let errors: Vec<f32> = lines
        .iter()
        .zip(&estimates)
        .map(|(l, e)| {
            assert!((l.t - e.t).abs() < 1e-6, "estimates carry the scan stamps: {} vs {}", l.t, e.t);
            l.truth_pose().expect("truth").distance(&Pose2::new(e.pose[0], e.pose[1], e.pose[2]))
        })
        .collect();
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    let last = *errors.last().expect("errors");
    println!("localize --bag: mean position error {:.1} cm, final {:.1} cm", mean * 100.0, last * 100.0);
    assert!(
        mean < 0.05 && last < 0.1,
        "mean error {mean} m (expected < 0.05), final {last} m (< 0.1): {errors:?}"
    );
}

#[test]
fn bag_localize_matches_the_jsonl_log_of_the_same_data() {
    let lines = drive(&room());
    // Odometry at every scan stamp and halfway between: the pose at each scan is a message's own.
    let taus = (0..2 * SCANS).map(|k| k as f64 * SCAN_PERIOD_S / 2.0);
    let f = files(&bag_with_odometry(&lines, taus));
    let log = f.dir.join("drive.jsonl");
    let no_truth: Vec<LogLine> = lines.iter().map(|l| LogLine { truth: None, ..l.clone() }).collect();
    std::fs::write(&log, to_jsonl(&no_truth).expect("serialise")).expect("log written");

    let (from_bag, from_log) = (f.dir.join("bag_est.jsonl"), f.dir.join("log_est.jsonl"));
    localize_bag(&f, &from_bag);
    let init = init_arg();
    let args = ["apfn", "localize", "--map", s(&f.yaml), "--log", s(&log), "--init", &init, "--seed", "4"];
    run(parse(&[&args[..], &["--out", s(&from_log)]].concat())).expect("localize --log runs");

    let (a, b) = (read_estimates(&from_bag), read_estimates(&from_log));
    assert_eq!(a.len(), b.len(), "one estimate per scan on both paths");
    let mut largest_gap = 0.0f32;
    for (x, y) in a.iter().zip(&b) {
        let gap = (0..3).map(|i| (x.pose[i] - y.pose[i]).abs()).fold(0.0, f32::max);
        assert!(x.t == y.t && gap < 1e-4, "bag and log estimates agree: {x:?} vs {y:?}");
        largest_gap = largest_gap.max(gap);
    }
    println!("--bag vs --log: estimates differ by at most {largest_gap:.1e} (m or rad)");
}

#[test]
fn bag_reader_interpolates_odometry_and_keeps_non_finite_ranges() {
    let lines = drive(&room());
    let bag = bag_with_odometry(&lines, odometry_30hz());
    let read = parse_bag(&bag, Path::new("drive.mcap"), &BagTopics::default()).expect("bag reads");
    assert_eq!((read.scans, read.odometry, read.dropped()), (SCANS, SCANS * 3 + 3, 0));
    assert_eq!(read.scan_frame, "base_scan");
    assert_eq!(read.odom_frames, ("odom".to_string(), "base_footprint".to_string()));
    for (got, want) in read.lines.iter().zip(&lines) {
        let gap = got.odom_pose().distance(&want.odom_pose());
        assert!(gap < 2e-3, "odometry interpolated at the scan stamp {}: off by {gap} m", got.t);
        assert_eq!(
            (got.t, got.angle_min, got.angle_increment),
            (want.t, want.angle_min, want.angle_increment)
        );
        let same = |a: f32, b: f32| a == b || (a.is_nan() && b.is_nan());
        assert!(got.ranges.iter().zip(&want.ranges).all(|(&a, &b)| same(a, b)), "ranges as recorded");
    }
    let all = || read.lines.iter().flat_map(|l| &l.ranges);
    assert!(all().any(|r| r.is_infinite()) && all().any(|r| r.is_nan()), "the bag held ∞ and NaN ranges");
}

#[test]
fn bag_reader_reads_big_endian_uncompressed_files_and_other_topics() {
    let lines = drive(&room())[..5].to_vec();
    let mut bag = BagWriter::new(false).expect("writer");
    let scans = bag.add_scan_topic("/robot/scan").expect("topic");
    let odom = bag.add_odometry_topic("/robot/odom").expect("topic");
    let imu = bag.add_topic("/imu", "sensor_msgs/msg/Imu", "").expect("topic");
    for line in &lines {
        let msg = OdometryMsg::planar(Header::at(line.t, "odom"), "base_link", line.odom_pose());
        bag.write(odom, line.t, &msg.encode(false)).expect("odometry");
        bag.write(imu, line.t, &[0, 1, 0, 0]).expect("an unrelated message");
        bag.write(scans, line.t, &scan_message(line).encode(false)).expect("scan");
    }
    let bytes = bag.finish().expect("finished");
    let topics = BagTopics { scan: "/robot/scan".into(), odom: "/robot/odom".into() };
    let read = parse_bag(&bytes, Path::new("be.mcap"), &topics).expect("big-endian CDR reads");
    assert_eq!(read.lines.len(), 5);
    for (got, want) in read.lines.iter().zip(&lines) {
        assert!(got.odom_pose().distance(&want.odom_pose()) < 1e-6, "odometry at the scan's own stamp");
        assert_eq!(got.range_max, want.range_max);
    }
}

#[test]
fn bag_reader_drops_scans_outside_the_odometry() {
    let lines = drive(&room())[..20].to_vec();
    // Odometry from the 5th scan's stamp to the 15th's: scans 0–3 and 15–19 have none around them.
    let read_with = |taus: Vec<f64>| {
        parse_bag(&bag_with_odometry(&lines, taus.into_iter()), Path::new("d.mcap"), &BagTopics::default())
            .map_err(|e| e.to_string())
    };
    let read: BagLog = read_with((4..=14).map(|k| k as f64 * SCAN_PERIOD_S).collect()).expect("reads");
    assert_eq!((read.scans, read.lines.len(), read.dropped()), (20, 11, 9));
    assert_eq!(read.lines[0].t, lines[4].t, "the first kept scan is the first inside the odometry");
    let err = read_with(vec![100.0, 101.0]).expect_err("no scan overlaps");
    assert!(err.contains("d.mcap") && err.contains("/scan") && err.contains("/odom"), "{err}");
}

/// The error of `localize --bag` on `bytes`, with `extra` flags.
fn cli_error(bytes: &[u8], extra: &[&str]) -> String {
    let f = files(bytes);
    let out = f.dir.join("never.jsonl");
    let args = ["apfn", "localize", "--map", s(&f.yaml), "--bag", s(&f.bag), "--task", "global"];
    let err = run(parse(&[&args[..], extra, &["--out", s(&out)]].concat())).expect_err("must fail");
    assert!(!out.exists(), "nothing is written when the bag is rejected");
    let text = format!("{err:#}");
    assert!(text.contains("drive.mcap"), "the error names the file: {text}");
    text
}

#[test]
fn bag_errors_name_the_file_the_topic_and_what_exists() {
    let lines = drive(&room())[..10].to_vec();
    let good = log_to_bag(&lines, &BagTopics::default()).expect("bag");

    let err = cli_error(&good, &["--scan-topic", "/base_scan"]);
    assert!(
        err.contains("/base_scan")
            && err.contains("--scan-topic")
            && err.contains("/scan (sensor_msgs/msg/LaserScan, 10 messages)")
            && err.contains("/odom (nav_msgs/msg/Odometry, 10 messages)"),
        "a missing topic lists the topics that exist with their types: {err}"
    );
    let err = cli_error(&good, &["--odom-topic", "/scan"]);
    assert!(
        err.contains("topic /scan (set by --odom-topic) carries sensor_msgs/msg/LaserScan")
            && err.contains("expected nav_msgs/msg/Odometry"),
        "a topic of another type names both types: {err}"
    );

    let mut empty = lines.clone();
    empty[3].ranges.clear();
    let err = cli_error(&log_to_bag(&empty, &BagTopics::default()).expect("bag"), &[]);
    assert!(
        err.contains("topic /scan, message 4") && err.contains("`ranges`") && err.contains("empty scan"),
        "{err}"
    );

    let err = cli_error(&good[..good.len() / 2], &[]);
    assert!(err.contains("cut short") && err.contains("mcap recover"), "a truncated file says so: {err}");
    let mut flipped = good.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0xff;
    let err = cli_error(&flipped, &[]);
    assert!(err.contains("corrupt MCAP file"), "a flipped byte inside a chunk is caught: {err}");
    let err = cli_error(b"{\"t\": 0.1}\n", &[]);
    assert!(err.contains("not an MCAP file"), "a JSON log passed as --bag: {err}");

    let mut cut_scan = BagWriter::new(false).expect("writer");
    let odom = cut_scan.add_odometry_topic("/odom").expect("topic");
    let scans = cut_scan.add_scan_topic("/scan").expect("topic");
    let msg = OdometryMsg::planar(Header::at(1.0, "odom"), "base_link", Pose2::default());
    cut_scan.write(odom, 1.0, &msg.encode(true)).expect("odometry");
    cut_scan.write(scans, 1.0, &scan_message(&lines[0]).encode(true)).expect("scan");
    cut_scan.write(scans, 1.0, &[0, 1, 0, 0, 9]).expect("a scan that ends inside its stamp");
    let err = cli_error(&cut_scan.finish().expect("bag"), &[]);
    assert!(err.contains("topic /scan, message 2") && err.contains("header.stamp.sec"), "{err}");

    let args =
        ["apfn", "localize", "--map", "m.yaml", "--log", "l.jsonl", "--scan-topic", "/s", "--out", "e"];
    let err = Cli::try_parse_from(args).expect_err("--scan-topic needs --bag").to_string();
    assert!(err.contains("--scan-topic") && err.contains("--log"), "{err}");
    let both = ["apfn", "localize", "--map", "m.yaml", "--log", "l.jsonl", "--bag", "b.mcap", "--out", "e"];
    assert!(Cli::try_parse_from(both).is_err(), "--log and --bag exclude each other");
    let neither = ["apfn", "localize", "--map", "m.yaml", "--out", "e"];
    assert!(Cli::try_parse_from(neither).is_err(), "one of --log and --bag is required");
}

#[test]
fn bag_odometry_with_a_zero_quaternion_is_refused() {
    let lines = drive(&room())[..3].to_vec();
    let mut bag = BagWriter::new(true).expect("writer");
    let odom = bag.add_odometry_topic("/odom").expect("topic");
    let scans = bag.add_scan_topic("/scan").expect("topic");
    for (k, line) in lines.iter().enumerate() {
        let mut msg = OdometryMsg::planar(Header::at(line.t, "odom"), "base_link", line.odom_pose());
        if k == 1 {
            msg.orientation = [0.0; 4];
        }
        bag.write(odom, line.t, &msg.encode(true)).expect("odometry");
        bag.write(scans, line.t, &scan_message(line).encode(true)).expect("scan");
    }
    let err = parse_bag(&bag.finish().expect("bag"), Path::new("q.mcap"), &BagTopics::default())
        .expect_err("a zero quaternion has no heading")
        .to_string();
    assert!(err.contains("q.mcap: topic /odom, message 2") && err.contains("quaternion"), "{err}");
}

#[test]
fn bag_reader_never_panics_on_damaged_bytes() {
    let lines = drive(&room())[..4].to_vec();
    let topics = BagTopics::default();
    let zstd = log_to_bag(&lines, &topics).expect("bag");
    let mut plain = BagWriter::new(false).expect("writer");
    let (scans, odom) =
        (plain.add_scan_topic("/scan").expect("t"), plain.add_odometry_topic("/odom").expect("t"));
    for line in &lines {
        let msg = OdometryMsg::planar(Header::at(line.t, "odom"), "base_link", line.odom_pose());
        plain.write(odom, line.t, &msg.encode(true)).expect("odometry");
        plain.write(scans, line.t, &scan_message(line).encode(true)).expect("scan");
    }
    let plain = plain.finish().expect("bag");
    let path = Path::new("fuzz.mcap");
    let mut rng = Pcg64Mcg::seed_from_u64(17);
    for bytes in [&zstd, &plain] {
        assert!(parse_bag(bytes, path, &topics).is_ok(), "the undamaged bag reads");
        for cut in 0..bytes.len() {
            assert!(parse_bag(&bytes[..cut], path, &topics).is_err(), "a bag cut at byte {cut} is an error");
        }
        for _ in 0..2000 {
            let mut damaged = bytes.clone();
            for _ in 0..rng.random_range(1..4) {
                let at = rng.random_range(0..damaged.len());
                damaged[at] = rng.random();
            }
            let _ = parse_bag(&damaged, path, &topics); // must return, Ok or Err
        }
    }
    let noise: Vec<u8> = b"\x89MCAP0\r\n".iter().copied().chain((0..4096).map(|_| rng.random())).collect();
    assert!(parse_bag(&noise, path, &topics).is_err(), "random bytes after the magic are an error");
}
