//! `apfn localize`: runs the classical particle filter (MCL with the likelihood-field or the beam
//! model) on a recorded JSON Lines log or ROS 2 bag and a ROS map, writing one estimate per scan —
//! how users localize their own robot's data, and how apfn is compared with other localizers on
//! identical input.
//!
//! Start: tracking and semi-global draw around `--init` when given (used as it is), else around
//! the first line's `truth` perturbed as the task prescribes; global needs neither. Every input
//! is checked (map, every log line, the flags) before the filter runs. The command prints the
//! start it assumed, and after the run how well the scans fit the map at the estimates (a log
//! from another map, or a lost filter, is warned about).

use crate::cli::count;
use crate::cli::progress::progress_bar;
use crate::particles::{
    ConvergedScale, InitParams, KldParams, MapFeatures, PfNetLikelihoodParams, ResampleParams, Task,
};
use crate::replay::bag::{BagLog, BagTopics, read_bag};
use crate::replay::{
    EstimateLine, FIT_TOLERANCE_M, InitialGuess, Localizer, LocalizerParams, LogLine, MIN_FIT, ReplayModel,
    SHIPPED_PFNET, read_log, to_jsonl,
};
use crate::sense::ScanMatchingParams;
use crate::world::map::{load_ros_map, write_atomically};
use crate::world::{Pose2, angle_error, wrap_angle};
use anyhow::{Context, ensure};
use bevy::prelude::default;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone, Debug, PartialEq)]
#[command(group(clap::ArgGroup::new("input").required(true).args(["log", "bag"])))]
pub struct LocalizeArgs {
    /// ROS map_server YAML of the map the log was recorded in.
    #[arg(long)]
    pub map: PathBuf,
    /// The log: one JSON object per line {t, odom, ranges, angle_min, angle_increment, range_min,
    /// range_max, truth?}.
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// Or a ROS 2 bag: a rosbag2 MCAP file (`ros2 bag record -s mcap /scan /odom`) with
    /// sensor_msgs/msg/LaserScan and nav_msgs/msg/Odometry; the odometry is interpolated at each
    /// scan's header stamp.
    #[arg(long, value_name = "FILE.mcap")]
    pub bag: Option<PathBuf>,
    /// The bag's LaserScan topic [default: /scan].
    #[arg(long, conflicts_with = "log")]
    pub scan_topic: Option<String>,
    /// The bag's Odometry topic [default: /odom].
    #[arg(long, conflicts_with = "log")]
    pub odom_topic: Option<String>,
    /// Particles. Default: the task's paper count (tracking 300, semi_global 500, global 3000).
    #[arg(long)]
    pub particles: Option<usize>,
    /// How much is known about the start: tracking, semi_global or global.
    #[arg(long, value_enum, default_value = "tracking")]
    pub task: Task,
    /// Initial guess `x,y,θ` (metres, metres, radians) for tracking and semi_global.
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true, value_name = "X,Y,THETA")]
    pub init: Option<Pose2>,
    /// Observation model: likelihood_field (AMCL's default), beam (ray casts, slower) or
    /// pfnet[:CHECKPOINT] (the learned model; default: the shipped models/pfnet_compact.safetensors,
    /// relative to the working directory).
    #[arg(long, alias = "model", value_parser = parse_localizer, default_value = "likelihood_field")]
    pub localizer: LocalizerChoice,
    /// PF-net's map features: exact (crop + map encoder per particle, the paper) or cached (crops
    /// of feature banks encoded once per map; faster, slightly less accurate).
    #[arg(long, value_enum, default_value = "exact")]
    pub features: MapFeatures,
    /// PF-net's log-likelihoods multiplied by S before weighing (> 1 sharpens the belief; the
    /// scan-laid wide-view checkpoint, models/pfnet_compact_scan_wide.safetensors, tracks the real
    /// maps best at 10).
    #[arg(long, value_name = "S")]
    pub likelihood_scale: Option<f32>,
    /// PF-net's log-likelihoods multiplied by SCALE instead once the belief has converged (the
    /// particles' position spread below SPREAD metres): the passive table's setting for the
    /// scan-laid wide-view checkpoint is 0.5,10 (sharp on a converged belief, not on a broad one).
    #[arg(long, value_parser = parse_converged, value_name = "SPREAD,SCALE")]
    pub converged_scale: Option<ConvergedScale>,
    /// Seed of the filter's random streams; the same seed gives the same estimates.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Soft-resampling mix α in [0, 1] (PF-net: 0.5; 1 = classical hard resampling).
    #[arg(long)]
    pub alpha: Option<f32>,
    /// Adapt the particle count by KLD-sampling between MIN and MAX particles, as nav2's AMCL
    /// does (its defaults: 500,2000); the filter starts with MAX unless `--particles` is given.
    #[arg(long, value_parser = parse_range, value_name = "MIN,MAX")]
    pub kld: Option<(usize, usize)>,
    /// Align each scan with the one before to narrow the odometry's heading change (laser
    /// odometry: a correlative search ±15° around the odometry's; a matched heading is then drawn
    /// with 0.5° of noise instead of the transition's 5°).
    #[arg(long)]
    pub scan_matching: bool,
    /// Where to write the estimates (JSON Lines {t, pose, cov, update_ms}, written atomically).
    #[arg(long)]
    pub out: PathBuf,
}

/// `--localizer`: the observation model, and for PF-net the checkpoint when one is named.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalizerChoice {
    pub model: ReplayModel,
    pub checkpoint: Option<String>,
}

/// How far the estimates were from the log's `truth`, over the lines that have one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthErrors {
    /// Lines with a `truth`.
    pub lines: usize,
    /// Mean position error, metres.
    pub mean_position_m: f32,
    /// Mean absolute heading error, radians.
    pub mean_heading_rad: f32,
    /// Position error on the last line with a truth, metres.
    pub final_position_m: f32,
}

pub fn run(args: LocalizeArgs) -> anyhow::Result<()> {
    let params = localizer_params(&args)?;
    let map = load_ros_map(&args.map).with_context(|| format!("--map {}", args.map.display()))?;
    let (input, lines) = read_input(&args)?;
    let guess = initial_guess(&args, &lines[0]);
    let mut filter = Localizer::new(map, params, guess, args.seed)
        .with_context(|| format!("starting the filter on map {} and {input}", args.map.display()))?;
    println!("{}", start_line(&filter, guess));
    println!("each scan runs the systems {}", filter.systems().join(" → "));
    if filter.fell_back_to_global() {
        eprintln!(
            "warning: the semi-global box around the initial guess holds no traversable cell; drew globally"
        );
    }
    let start_particles = filter.particles().len();

    let bar = progress_bar(lines.len() as u64, "{bar:40} {pos}/{len} scans, {per_sec}, eta {eta}");
    let estimates = filter.replay(&lines, || bar.inc(1));
    bar.finish_and_clear();

    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    write_atomically(&args.out, to_jsonl(&estimates)?.as_bytes())?;
    let mean_ms = estimates.iter().map(|e| e.update_ms).sum::<f64>() / estimates.len() as f64;
    let particles = match &filter.params().resample.kld {
        Some(k) => format!(
            "KLD-sampling between {} and {} particles: {start_particles} at the start, {} at the end",
            k.min_particles,
            k.max_particles,
            filter.particles().len()
        ),
        None => count(start_particles as u64, "particle"),
    };
    println!(
        "localized {} with {particles}; {mean_ms:.2} ms per update; wrote {}",
        count(estimates.len() as u64, "scan"),
        args.out.display()
    );
    if let Some(fit) = log_fit(&filter, &lines, &estimates) {
        let fit_line = format!(
            "seen from the estimates, {:.0} % of the scans' beams end within {FIT_TOLERANCE_M} m of an \
             occupied cell",
            fit * 100.0
        );
        if filter.params().model == ReplayModel::Pfnet {
            // PF-net's estimates are tens of centimetres coarse (docs/results/passive.md), so the
            // 0.2 m check cannot tell a wrong map from a coarse estimate: report, do not warn.
            println!(
                "map check: {fit_line} (PF-net's estimates are coarser than MCL's: expect less than 99 %)"
            );
        } else if fit < MIN_FIT {
            eprintln!(
                "warning: the log does not fit map {}: {fit_line} (a log localized on its own map scores 99 % \
                 or more). Was it recorded on another map, or did the filter start in the wrong place \
                 (check --init, or try --task global)?",
                args.map.display()
            );
        } else {
            println!("map check: {fit_line}");
        }
    }
    if let Some(e) = truth_errors(&lines, &estimates) {
        println!(
            "vs truth on {}: mean position error {:.1} cm, mean |heading error| {:.3} rad, final {:.1} cm",
            count(e.lines as u64, "line"),
            e.mean_position_m * 100.0,
            e.mean_heading_rad,
            e.final_position_m * 100.0
        );
    }
    let health = filter.health();
    if health.degeneracies > 0 {
        eprintln!(
            "warning: the weights degenerated {} and were reset to uniform",
            count(health.degeneracies, "time")
        );
    }
    Ok(())
}

/// The lines to localize from `--log` or `--bag`, and what they came from ("log F" / "bag F").
/// For a bag, prints what was read: counts, frames and scans dropped for lack of odometry.
fn read_input(args: &LocalizeArgs) -> anyhow::Result<(String, Vec<LogLine>)> {
    let ((Some(path), None) | (None, Some(path))) = (&args.log, &args.bag) else {
        anyhow::bail!("expected exactly one of --log and --bag");
    };
    if args.log.is_some() {
        return Ok((format!("log {}", path.display()), read_log(path)?));
    }
    let defaults = BagTopics::default();
    let topics = BagTopics {
        scan: args.scan_topic.clone().unwrap_or(defaults.scan),
        odom: args.odom_topic.clone().unwrap_or(defaults.odom),
    };
    let bag = read_bag(path, &topics)?;
    println!("{}", bag_line(path, &topics, &bag));
    Ok((format!("bag {}", path.display()), bag.lines))
}

/// What `--bag` read, in one line.
fn bag_line(path: &Path, topics: &BagTopics, bag: &BagLog) -> String {
    let (odom_frame, base_frame) = &bag.odom_frames;
    let dropped = match bag.dropped() {
        0 => String::new(),
        n => format!("; dropped {} outside the odometry's time span", count(n as u64, "scan")),
    };
    format!(
        "read {} of {} (frame `{}`) and {} of {} (`{odom_frame}` → `{base_frame}`) from {}{dropped}",
        count(bag.scans as u64, "scan"),
        topics.scan,
        bag.scan_frame,
        count(bag.odometry as u64, "odometry message"),
        topics.odom,
        path.display()
    )
}

/// Mean [`scan_fit`](crate::replay::scan_fit) of every scan at its estimate; `None` when no scan
/// has a usable beam.
fn log_fit(filter: &Localizer, lines: &[LogLine], estimates: &[EstimateLine]) -> Option<f32> {
    let fits: Vec<f32> = lines
        .iter()
        .zip(estimates)
        .filter_map(|(line, e)| filter.scan_fit(&line.scan(), &Pose2::new(e.pose[0], e.pose[1], e.pose[2])))
        .collect();
    (!fits.is_empty()).then(|| fits.iter().sum::<f32>() / fits.len() as f32)
}

/// What the filter assumed about the start, in the command line's words.
fn start_line(filter: &Localizer, guess: InitialGuess) -> String {
    let init = &filter.params().init;
    let (task, n) = (init.task, filter.particles().len());
    let around = |centre: Pose2| format!("({:.2}, {:.2}, {:.2})", centre.x, centre.y, centre.yaw);
    let spread = match task {
        Task::Tracking => {
            format!("Gaussian (σ {} m, {}°)", init.tracking_sigma_m, init.tracking_sigma_deg)
        }
        _ => format!("uniform over the traversable cells of a {} m box", init.semi_global_box_m),
    };
    let source = match guess {
        _ if task == Task::Global => {
            return format!("start: --task {}, {n} particles uniform over the map", task.name());
        }
        InitialGuess::Pose(pose) => format!("around --init {}", around(pose)),
        InitialGuess::PerturbedTruth(truth) => format!(
            "around the log's first `truth` {} moved by N(0, {} m, {}°), as the simulator perturbs the \
             task's guess (give your own with --init X,Y,THETA)",
            around(truth),
            init.tracking_sigma_m,
            init.tracking_sigma_deg
        ),
        InitialGuess::Unknown => {
            unreachable!("Localizer::new refuses a tracking or semi-global start without a guess")
        }
    };
    format!("start: --task {}, {n} particles, {spread} {source}", task.name())
}

/// The filter's params from the flags; rejects `--particles 0` and α outside [0, 1].
pub fn localizer_params(args: &LocalizeArgs) -> anyhow::Result<LocalizerParams> {
    ensure!(args.particles != Some(0), "--particles 0: expected at least 1 particle");
    if let Some(scale) = args.likelihood_scale {
        ensure!(scale.is_finite() && scale > 0.0, "--likelihood-scale {scale}: expected a finite factor > 0");
    }
    ensure!(
        args.localizer.model == ReplayModel::Pfnet
            || (args.likelihood_scale.is_none() && args.converged_scale.is_none()),
        "--likelihood-scale, --converged-scale: only PF-net's log-likelihoods are scaled (--localizer pfnet)"
    );
    let defaults = LocalizerParams::default();
    let kld = args.kld.map(|(min_particles, max_particles)| KldParams {
        min_particles,
        max_particles,
        ..default()
    });
    let particles = args.particles.or(kld.as_ref().map(|k| k.max_particles));
    let params = LocalizerParams {
        init: InitParams { task: args.task, particles, ..defaults.init },
        model: args.localizer.model,
        pfnet: PfNetLikelihoodParams {
            checkpoint: Some(args.localizer.checkpoint.clone().unwrap_or_else(|| SHIPPED_PFNET.into())),
            features: args.features,
            likelihood_scale: args.likelihood_scale.unwrap_or(defaults.pfnet.likelihood_scale),
            converged: args.converged_scale,
            ..defaults.pfnet
        },
        resample: ResampleParams {
            alpha: args.alpha.unwrap_or(defaults.resample.alpha),
            kld,
            ..defaults.resample
        },
        scan_matching: args.scan_matching.then(ScanMatchingParams::default),
        ..LocalizerParams::default()
    };
    params.validate().context("--alpha: expected a value in [0, 1]; --kld: expected 1 ≤ MIN ≤ MAX")?;
    Ok(params)
}

/// `--init` as given, else the first line's truth (perturbed by the task), else nothing.
pub fn initial_guess(args: &LocalizeArgs, first: &LogLine) -> InitialGuess {
    match (args.init, first.truth_pose()) {
        (Some(pose), _) => InitialGuess::Pose(pose),
        (None, Some(truth)) => InitialGuess::PerturbedTruth(truth),
        (None, None) => InitialGuess::Unknown,
    }
}

/// Position and heading errors of `estimates` against the `truth` of the matching `lines`;
/// `None` when no line has a truth.
pub fn truth_errors(lines: &[LogLine], estimates: &[EstimateLine]) -> Option<TruthErrors> {
    let pairs: Vec<(f32, f32)> = lines
        .iter()
        .zip(estimates)
        .filter_map(|(line, e)| {
            let truth = line.truth_pose()?;
            let pose = Pose2::new(e.pose[0], e.pose[1], e.pose[2]);
            Some((pose.distance(&truth), angle_error(pose.yaw, truth.yaw)))
        })
        .collect();
    let (&(final_position_m, _), n) = (pairs.last()?, pairs.len() as f32);
    Some(TruthErrors {
        lines: pairs.len(),
        mean_position_m: pairs.iter().map(|p| p.0).sum::<f32>() / n,
        mean_heading_rad: pairs.iter().map(|p| p.1).sum::<f32>() / n,
        final_position_m,
    })
}

/// `likelihood_field`, `beam`, `pfnet` or `pfnet:CHECKPOINT`.
fn parse_localizer(text: &str) -> Result<LocalizerChoice, String> {
    let (name, checkpoint) = match text.split_once(':') {
        Some((name, path)) => (name, Some(path.to_owned())),
        None => (text, None),
    };
    let model = <ReplayModel as clap::ValueEnum>::from_str(name, false)
        .map_err(|_| format!("expected likelihood_field, beam, pfnet or pfnet:CHECKPOINT, found `{text}`"))?;
    match (model, &checkpoint) {
        (ReplayModel::Pfnet, Some(path)) if path.is_empty() => {
            Err("pfnet: expected a checkpoint path after `:`".into())
        }
        (ReplayModel::Pfnet, _) | (_, None) => Ok(LocalizerChoice { model, checkpoint }),
        (_, Some(_)) => Err(format!("`{name}` takes no checkpoint; only pfnet:CHECKPOINT does")),
    }
}

/// `MIN,MAX` particle counts for `--kld`.
fn parse_range(text: &str) -> Result<(usize, usize), String> {
    let count =
        |s: &str| s.trim().parse::<usize>().map_err(|_| format!("expected a particle count, found `{s}`"));
    match text.split_once(',') {
        Some((min, max)) => Ok((count(min)?, count(max)?)),
        None => Err(format!("expected MIN,MAX (e.g. 500,2000), found `{text}`")),
    }
}

/// `SPREAD,SCALE`: two finite numbers > 0 (metres, factor).
fn parse_converged(text: &str) -> Result<ConvergedScale, String> {
    let positive = |name: &str, s: &str| match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{name}: expected a finite number > 0, found `{s}`")),
    };
    match text.split_once(',') {
        Some((spread, scale)) => Ok(ConvergedScale {
            spread_m: positive("SPREAD", spread)?,
            likelihood_scale: positive("SCALE", scale)?,
        }),
        None => Err(format!("expected SPREAD,SCALE (e.g. 0.5,10), found `{text}`")),
    }
}

/// `x,y,θ`: three comma-separated finite numbers (metres, metres, radians).
fn parse_pose(text: &str) -> Result<Pose2, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [x, y, yaw] = parts.as_slice() else {
        return Err(format!("expected 3 comma-separated numbers x,y,θ, found {} value(s)", parts.len()));
    };
    let number = |name: &str, s: &str| match s.parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{name}: expected a finite number, found `{s}`")),
    };
    Ok(Pose2::new(number("x", x)?, number("y", y)?, wrap_angle(number("θ", yaw)?)))
}
