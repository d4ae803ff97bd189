//! `apfn pfnet landscape`: where, and how sharply, a PF-net's likelihood peaks around the true
//! pose, axis by axis, beside the likelihood field's on the same scans. A filter's error is
//! bounded by its observation model's: a peak off the truth is a bias no number of steps removes,
//! a broad one a resolution the filter inherits.
//!
//! For each of `poses` true poses drawn on the map's traversable space, the noise-free scan is
//! cast and rasterised as the simulator's `lidar` and `local_grid` steps do; then particles are
//! laid on three slices through the truth — forward, leftward (the robot's own frame) and heading
//! — and each model scores them. Per slice the table reports the peak's offset and the spread of
//! the slice's normalised likelihood (the filter's weights over that slice).

use crate::cli::set_threads;
use crate::compose::NETWORK_RESOLUTION_M;
use crate::nn::pfnet::{PfNet, Workspaces, depth_image};
use crate::particles::{LikelihoodFieldParams, ParticleSet, add_log_likelihoods, local_grid_for, map_view};
use crate::sense::{
    DepthParams, LidarParams, LidarScan, LocalGridParams, RayGrid, cast_scan, depth_strip, rasterize_scan,
};
use crate::world::map::procedural::{ApartmentParams, generate_apartment};
use crate::world::map::{DistanceField, NetworkMap, OccupancyMap, TraversableMap, load_ros_map};
use crate::world::{Pose2, RobotParams};
use anyhow::Context;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct LandscapeArgs {
    /// A PF-net checkpoint, e.g. `models/pfnet_compact.safetensors`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// A ROS map YAML to draw the true poses on (or use --apartment).
    #[arg(long, conflicts_with = "apartment", required_unless_present = "apartment")]
    pub map: Option<PathBuf>,
    /// The procedural apartment with this seed (the paper-size range the networks train on) instead
    /// of a file: seeds below 1,000,000 are the seen split, above it the unseen one.
    #[arg(long)]
    pub apartment: Option<u64>,
    /// True poses drawn on the map's traversable space.
    #[arg(long, default_value_t = 50)]
    pub poses: usize,
    /// Seed of the true poses.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Half-width of the forward and leftward slices, metres.
    #[arg(long, default_value_t = 1.0)]
    pub span_m: f32,
    /// Half-width of the heading slice, radians.
    #[arg(long, default_value_t = 0.5)]
    pub span_rad: f32,
    /// Particles per slice, the truth among them (odd).
    #[arg(long, default_value_t = 41)]
    pub points: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// The three slices through the true pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Axis {
    Forward,
    Left,
    Heading,
}

impl Axis {
    const ALL: [Axis; 3] = [Axis::Forward, Axis::Left, Axis::Heading];

    fn name(self) -> &'static str {
        match self {
            Axis::Forward => "forward_m",
            Axis::Left => "left_m",
            Axis::Heading => "heading_rad",
        }
    }

    /// `truth` moved by `offset` along this axis (metres in its own frame, or radians).
    fn offset(self, truth: Pose2, offset: f32) -> Pose2 {
        match self {
            Axis::Forward => truth.compose(&Pose2::new(offset, 0.0, 0.0)),
            Axis::Left => truth.compose(&Pose2::new(0.0, offset, 0.0)),
            Axis::Heading => truth.compose(&Pose2::new(0.0, 0.0, offset)),
        }
    }
}

/// One model's log-likelihoods on one slice, summarised.
#[derive(Clone, Copy, Debug, PartialEq)]
struct SliceSummary {
    /// Offset of the highest log-likelihood.
    peak: f32,
    /// Mean and standard deviation of the offsets under the slice's normalised likelihood.
    mean: f32,
    spread: f32,
    /// Highest minus lowest log-likelihood: how many nats the slice's ends lose to its peak.
    depth: f32,
}

fn summarise(offsets: &[f32], loglik: &[f32]) -> SliceSummary {
    let best = loglik.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let worst = loglik.iter().copied().fold(f32::INFINITY, f32::min);
    let peak = offsets[loglik.iter().position(|&l| l == best).unwrap_or(0)];
    let weights: Vec<f64> = loglik.iter().map(|&l| f64::from(l - best).exp()).collect();
    let total: f64 = weights.iter().sum();
    let mean = offsets.iter().zip(&weights).map(|(&o, w)| f64::from(o) * w).sum::<f64>() / total;
    let var =
        offsets.iter().zip(&weights).map(|(&o, w)| (f64::from(o) - mean).powi(2) * w).sum::<f64>() / total;
    SliceSummary { peak, mean: mean as f32, spread: var.sqrt() as f32, depth: best - worst }
}

/// What the two models need of a map.
struct Scene {
    map: OccupancyMap,
    network: NetworkMap,
    rays: RayGrid,
    field: DistanceField,
    traversable: TraversableMap,
}

fn load_scene(args: &LandscapeArgs) -> anyhow::Result<Scene> {
    let map = match (&args.map, args.apartment) {
        (Some(path), _) => load_ros_map(path).with_context(|| format!("--map {}", path.display()))?,
        (None, Some(seed)) => generate_apartment(seed, &ApartmentParams::paper_size()),
        (None, None) => anyhow::bail!("expected --map FILE.yaml or --apartment SEED"),
    };
    let traversable = TraversableMap::build(&map, RobotParams::default().radius_m).map_err(|e| {
        anyhow::anyhow!(
            "{}: {e}",
            args.map.as_ref().map_or("--apartment".into(), |p| p.display().to_string())
        )
    })?;
    Ok(Scene {
        network: NetworkMap::from_fine(&map, NETWORK_RESOLUTION_M),
        rays: RayGrid::from_map(&map),
        field: DistanceField::build(&map),
        traversable,
        map,
    })
}

/// The observation image the network reads at `truth` (its grid, wide grid and depth channels).
fn observation(model: &PfNet, scene: &Scene, truth: Pose2, obs: &mut [f32]) -> LidarScan {
    let mut scan = LidarScan::default();
    cast_scan(&scene.rays, truth, &[], &LidarParams::default(), &mut scan);
    let grid = local_grid_for(&model.config);
    let (grid_channel, depth_channel, wide_channel) = model.config.split_observation(obs);
    if let Some(channel) = grid_channel {
        rasterize_scan(&scan, &grid, channel);
    }
    if let (Some(channel), Some(extent_m)) = (wide_channel, grid.wide_extent_m) {
        rasterize_scan(&scan, &LocalGridParams { extent_m, ..grid }, channel);
    }
    if let Some(channel) = depth_channel {
        let params = DepthParams::default();
        let mut depths = vec![0.0; params.columns];
        depth_strip(&scene.rays, truth, &params, &mut depths);
        depth_image(&depths, model.config.obs_cells, channel);
    }
    scan
}

/// Runs `apfn pfnet landscape`: prints one JSON object per model and axis.
pub fn run(args: &LandscapeArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    anyhow::ensure!(
        args.points >= 3 && args.points % 2 == 1,
        "--points: expected an odd count ≥ 3, found {}",
        args.points
    );
    crate::limits::EPISODES.check("--poses", args.poses).map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        args.span_m.is_finite() && args.span_m > 0.0 && args.span_m <= 10.0,
        "--span-m: expected more than 0 and at most 10 m, found {}",
        args.span_m
    );
    anyhow::ensure!(
        args.span_rad.is_finite() && args.span_rad > 0.0 && args.span_rad <= std::f32::consts::PI,
        "--span-rad: expected more than 0 and at most π rad, found {}",
        args.span_rad
    );
    let model = PfNet::load(&args.checkpoint)
        .with_context(|| format!("--checkpoint {}", args.checkpoint.display()))?;
    for row in landscape(&model, &load_scene(args)?, args)? {
        println!("{row}");
    }
    Ok(())
}

/// One JSON row per model (PF-net, then the likelihood field) and axis.
fn landscape(model: &PfNet, scene: &Scene, args: &LandscapeArgs) -> anyhow::Result<Vec<serde_json::Value>> {
    let mut rng = Pcg64Mcg::seed_from_u64(args.seed);
    let pool = Workspaces::for_current_pool();
    let field_params = LikelihoodFieldParams::default();
    let half = (args.points / 2) as f32;

    // [model][axis] → every pose's summary.
    let mut summaries = vec![vec![Vec::new(); 3]; 2];
    let mut obs = vec![0.0; model.obs_len()];
    let mut terms = vec![0.0; model.obs_term_len()];
    let owner = vec![0u32; args.points];
    let mut maps = vec![0.0; args.points * model.local_map_len()];
    let mut loglik = vec![0.0; args.points];
    let view = map_view(&scene.network);
    for _ in 0..args.poses {
        let truth = scene.traversable.sample_pose(&scene.map, &mut rng);
        let scan = observation(model, scene, truth, &mut obs);
        model.observation_terms_par(&obs, &mut terms, &pool);
        for (a, axis) in Axis::ALL.into_iter().enumerate() {
            let span = if axis == Axis::Heading { args.span_rad } else { args.span_m };
            let offsets: Vec<f32> = (0..args.points).map(|i| (i as f32 - half) / half * span).collect();
            let poses: Vec<Pose2> = offsets.iter().map(|&o| axis.offset(truth, o)).collect();
            let column = |f: fn(&Pose2) -> f32| poses.iter().map(f).collect::<Vec<f32>>();
            let (xs, ys, yaws) = (column(|p| p.x), column(|p| p.y), column(|p| p.yaw));
            model.crop_inputs(&view, (&xs, &ys, &yaws), &obs, &mut maps);
            model.log_likelihoods_exact(&terms, &owner, &maps, &mut loglik, &pool);
            summaries[0][a].push(summarise(&offsets, &loglik));
            let mut set = ParticleSet::from_poses(&poses);
            add_log_likelihoods(&mut set, &scan, &scene.field, &scene.map.origin, &field_params)
                .map_err(|e| anyhow::anyhow!("likelihood field: {e:?}"))?;
            summaries[1][a].push(summarise(&offsets, &set.log_w));
        }
    }
    let mut rows = Vec::new();
    for (name, per_axis) in ["pfnet", "likelihood_field"].into_iter().zip(&summaries) {
        for (axis, slices) in Axis::ALL.into_iter().zip(per_axis) {
            let mean = |f: fn(&SliceSummary) -> f32| slices.iter().map(f).sum::<f32>() / slices.len() as f32;
            rows.push(serde_json::json!({
                "model": name,
                "axis": axis.name(),
                "poses": slices.len(),
                "mean_abs_peak": round4(mean(|s| s.peak.abs())),
                "median_abs_peak": round4(median(slices.iter().map(|s| s.peak.abs()).collect())),
                "mean_peak": round4(mean(|s| s.peak)),
                "mean_abs_weighted_mean": round4(mean(|s| s.mean.abs())),
                "mean_spread": round4(mean(|s| s.spread)),
                "mean_depth_nats": round4(mean(|s| s.depth)),
            }));
        }
    }
    Ok(rows)
}

fn median(mut xs: Vec<f32>) -> f32 {
    xs.sort_by(f32::total_cmp);
    xs.get(xs.len() / 2).copied().unwrap_or(f32::NAN)
}

fn round4(x: f32) -> f64 {
    (f64::from(x) * 1e4).round() / 1e4
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pfnet::PfNetConfig;

    fn args() -> LandscapeArgs {
        LandscapeArgs {
            checkpoint: PathBuf::new(),
            map: None,
            apartment: Some(3),
            poses: 4,
            seed: 1,
            span_m: 0.5,
            span_rad: 0.3,
            points: 11,
            threads: None,
        }
    }

    #[test]
    fn a_slice_is_summarised_by_its_peak_weighted_mean_spread_and_depth() {
        let offsets = [-1.0, 0.0, 1.0];
        let flat = summarise(&offsets, &[0.0, 0.0, 0.0]);
        assert_eq!((flat.mean, flat.depth), (0.0, 0.0));
        assert!((flat.spread - (2.0f32 / 3.0).sqrt()).abs() < 1e-6, "{flat:?}");
        let ln2 = std::f32::consts::LN_2;
        let leaning = summarise(&offsets, &[-10.0, 0.0, -ln2]);
        assert_eq!(leaning.peak, 0.0);
        assert!((leaning.mean - 1.0 / 3.0).abs() < 1e-3, "weights 0 : 2/3 : 1/3 → {leaning:?}");
        assert!((leaning.depth - 10.0).abs() < 1e-6);
    }

    #[test]
    fn the_likelihood_field_peaks_on_the_truth_along_every_slice() {
        // The field is exact for a noise-free scan: a peak off the truth would mean the slices, the
        // scan or the model's frames disagree, which the PF-net rows would inherit.
        let scene = load_scene(&args()).expect("a procedural apartment");
        let model = PfNet::new(PfNetConfig::compact(), 0).expect("compact");
        let rows = landscape(&model, &scene, &args()).expect("runs");
        assert_eq!(rows.len(), 6, "two models × three slices");
        for row in rows.iter().filter(|r| r["model"] == "likelihood_field") {
            assert_eq!(row["poses"], 4);
            assert!(row["mean_abs_peak"].as_f64().unwrap() < 0.06, "{row}");
            assert!(row["mean_depth_nats"].as_f64().unwrap() > 5.0, "{row}");
        }
    }
}
