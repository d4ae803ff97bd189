//! The agent's view of the belief (paper §III-B): the particles projected onto the 0.1 m grid as
//! four channels — free space of the map, Σ weights per cell, Σ w·cos θ and Σ w·sin θ — cut out
//! as a square crop centred on and rotated to a pose hypothesis (the estimate, and optionally
//! further modes, see [`belief_modes`]).
//!
//! The paper projects the particles onto the whole map (H × W × 4) and then crops; projecting
//! straight into the crop gives the same cells at O(particles + crop) instead of O(H·W) per
//! step, so large maps cost nothing extra. Headings are stored relative to the crop's own
//! heading, so a belief that turns with the robot looks the same to the agent.
//!
//! With `history: h` the crops of the last h steps follow the present ones (frame stacking, as
//! DQN stacks Atari frames): the belief is the filter's memory of what the robot saw, but the
//! crop shows only 5 m of it, and a stack shows how that part has moved and sharpened.
//!
//! With `overview_m: Some(r)` one more crop of the same `cells`, at cell side r, follows the
//! modes' crops, centred on and turned to the estimate like the first: at 0.4 m it shows 20 m, the
//! whole of a paper-size apartment (at most 10 m a side) wherever the estimate lies in it, so an
//! agent whose belief is still spread sees all of it and the rooms around it.

use crate::belief::modes::belief_modes;
use crate::episode::EpisodeStart;
use crate::params::{StepParams, expect_param};
use crate::particles::{ParticleSet, PoseEstimate};
use crate::world::map::NetworkMap;
use crate::world::{OnMap, Pose2};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Channels per crop, in order: free space (1 − occupancy of the network map, 0 off the map),
/// Σ w, Σ w·cos(θ − θ_crop), Σ w·sin(θ − θ_crop).
pub const BELIEF_CHANNELS: usize = 4;

/// The coarsest overview cell, metres: 100 m across at 50 cells.
const MAX_OVERVIEW_M: f32 = 2.0;

/// Crop geometry and how many hypotheses to look at.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BeliefParams {
    /// Side of each crop, cells (DESIGN: 50, i.e. 5 m at 0.1 m).
    pub cells: usize,
    /// Cell side, metres (DESIGN: 0.1, the network map's resolution).
    pub resolution_m: f32,
    /// Crops per robot: the estimate, then the `modes − 1` heaviest other modes (paper: 1, "just
    /// using the mean position and orientation of the particles works well").
    pub modes: usize,
    /// Side of the square bins in which modes are found, metres (ours: 1.0).
    pub mode_bin_m: f32,
    /// Past agent steps whose crops follow the present ones, most recent first (paper: 0). At an
    /// episode's first step the past is the present repeated, so no episode shows the last one's.
    pub history: usize,
    /// Cell side of the coarse crop that shows the whole belief, metres (paper: none; ours 0.4
    /// where used). Its free-space channel is the mean of the map over each cell, so a thin
    /// wall still shows at a cell four times its width.
    pub overview_m: Option<f32>,
}

impl Default for BeliefParams {
    fn default() -> Self {
        Self { cells: 50, resolution_m: 0.1, modes: 1, mode_bin_m: 1.0, history: 0, overview_m: None }
    }
}

impl BeliefParams {
    /// Crops per agent step: the modes', then the overview if there is one.
    pub fn crops_per_step(&self) -> usize {
        self.modes + usize::from(self.overview_m.is_some())
    }

    /// Input channels of a network that reads these crops: 4 per crop, present and past steps.
    pub fn channels(&self) -> usize {
        BELIEF_CHANNELS * self.crops_per_step() * (1 + self.history)
    }
}

impl StepParams for BeliefParams {
    fn check(&self) -> Result<(), String> {
        crate::limits::RASTER_SIDE.check("cells", self.cells)?;
        expect_param(self.resolution_m > 0.0, "resolution_m", "a cell side > 0 m")?;
        expect_param(self.modes > 0, "modes", "at least 1 crop (the estimate)")?;
        expect_param(self.mode_bin_m > 0.0, "mode_bin_m", "a bin side > 0 m")?;
        if let Some(side) = self.overview_m {
            // Each overview cell averages (side / map resolution)² map samples: bounded, so an
            // absurd side is an error rather than a hang.
            let ok = side >= self.resolution_m && side <= MAX_OVERVIEW_M;
            expect_param(ok, "overview_m", "a cell side from resolution_m to 2 m")?;
        }
        crate::limits::BELIEF_HISTORY.check("history", self.history)
    }
}

/// A robot's belief crops, ready to be stacked into a batch: `(1 + history) × modes × 4 × cells ×
/// cells` values, the present step's crops first, row-major per channel (the NCHW layout of a
/// network input). Each crop has the layout of
/// `LocalGrid`: its centre pose at the crop's centre facing up, row 0 farthest ahead, column 0
/// farthest to the left.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct BeliefCrop {
    pub cells: usize,
    /// The pose each crop is centred on and rotated to, in crop order.
    pub centres: Vec<Pose2>,
    pub values: Vec<f32>,
}

impl BeliefCrop {
    /// Channel `channel` of crop `mode`: `cells²` values.
    pub fn channel(&self, mode: usize, channel: usize) -> &[f32] {
        let n = self.cells * self.cells;
        let start = (mode * BELIEF_CHANNELS + channel) * n;
        &self.values[start..start + n]
    }
}

/// Fills one crop (4 channels of `cells²` in `out`) centred on `centre`, cells of `resolution_m`:
/// the kernel of [`belief_crop`]. `weights` are the set's normalised weights (`set.weights()`,
/// computed once for all of a robot's crops).
pub fn project_crop(
    set: &ParticleSet,
    weights: &[f32],
    map: &NetworkMap,
    centre: &Pose2,
    (cells, resolution_m): (usize, f32),
    out: &mut [f32],
) {
    let (n, res) = (cells, resolution_m);
    let (area, half) = (n * n, n as f32 / 2.0);
    out.fill(0.0);
    let (free, rest) = out.split_at_mut(area);
    let (weight, rest) = rest.split_at_mut(area);
    let (cos, sin) = rest.split_at_mut(area);
    // Crop cell centres → the network map's grid: one affine map, set up once per crop. A cell
    // wider than the map's averages s × s points of it, so no wall falls between samples.
    let frame = map.origin.between(centre);
    let (fs, fc) = frame.yaw.sin_cos();
    let to_grid = 1.0 / map.resolution_m;
    let s = (res / map.resolution_m - 1e-3).ceil().max(1.0) as usize;
    let offsets: Vec<f32> = (0..s).map(|i| (i as f32 + 0.5) / s as f32 - 0.5).collect();
    for (row, cells) in free.chunks_mut(n).enumerate() {
        for (col, cell) in cells.iter_mut().enumerate() {
            let mut occupancy = 0.0;
            for &da in &offsets {
                let ahead = (half - row as f32 - 0.5 - da) * res;
                let (ax, ay) = (frame.x + fc * ahead, frame.y + fs * ahead);
                for &dl in &offsets {
                    let left = (half - col as f32 - 0.5 - dl) * res;
                    occupancy +=
                        map.occupancy_at_grid((ax - fs * left) * to_grid, (ay + fc * left) * to_grid);
                }
            }
            *cell = 1.0 - occupancy / (s * s) as f32;
        }
    }
    let (s0, c0) = centre.yaw.sin_cos();
    for (k, &w) in weights.iter().enumerate() {
        let (dx, dy) = (set.x[k] - centre.x, set.y[k] - centre.y);
        let (row, col) = (half - (c0 * dx + s0 * dy) / res, half - (c0 * dy - s0 * dx) / res);
        if row >= 0.0 && col >= 0.0 && row < n as f32 && col < n as f32 {
            let cell = row as usize * n + col as usize;
            let (s, c) = (set.yaw[k] - centre.yaw).sin_cos();
            weight[cell] += w;
            cos[cell] += w * c;
            sin[cell] += w * s;
        }
    }
}

/// Reads ParticleSet, PoseEstimate, OnMap → the map's NetworkMap, EpisodeStart, BeliefParams.
/// Writes BeliefCrop (spawned empty with every robot).
pub fn belief_crop(
    params: Res<BeliefParams>,
    maps: Query<&NetworkMap>,
    mut robots: Query<(&ParticleSet, &PoseEstimate, &OnMap, Has<EpisodeStart>, &mut BeliefCrop)>,
) {
    robots.par_iter_mut().for_each(|(set, estimate, on_map, starts, mut crop)| {
        let Ok(map) = maps.get(on_map.0) else {
            tracing::warn!("belief_crop: map {:?} has no NetworkMap", on_map.0);
            return;
        };
        let weights = set.weights();
        let centres = belief_modes(set, &weights, &estimate.pose, params.modes, params.mode_bin_m);
        let fine = (params.cells, params.resolution_m);
        let coarse = params.overview_m.map(|side| (estimate.pose, (params.cells, side)));
        let crops: Vec<_> = centres.iter().map(|&centre| (centre, fine)).chain(coarse).collect();
        let per_crop = BELIEF_CHANNELS * params.cells * params.cells;
        let present = per_crop * crops.len();
        let len = present * (1 + params.history);
        let fresh = starts || crop.values.len() != len;
        crop.values.resize(len, 0.0);
        // Each past step moves one place back; the oldest drops off the end.
        crop.values.copy_within(..len - present, present);
        for ((centre, geometry), out) in crops.iter().zip(crop.values[..present].chunks_mut(per_crop)) {
            project_crop(set, &weights, map, centre, *geometry, out);
        }
        if fresh {
            let (now, past) = crop.values.split_at_mut(present);
            past.chunks_exact_mut(present).for_each(|step| step.copy_from_slice(now));
        }
        crop.cells = params.cells;
        crop.centres = crops.iter().map(|(centre, _)| *centre).collect();
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use bevy::ecs::system::RunSystemOnce;

    fn room() -> NetworkMap {
        NetworkMap::from_fine(&tiny_room(), 0.1)
    }

    fn crop(poses: &[Pose2], weights: &[f32], centre: Pose2, params: &BeliefParams) -> Vec<f32> {
        let mut set = ParticleSet::from_poses(poses);
        set.log_w = weights.iter().map(|w| w.ln()).collect();
        let mut out = vec![f32::NAN; BELIEF_CHANNELS * params.cells * params.cells];
        project_crop(&set, &set.weights(), &room(), &centre, (params.cells, params.resolution_m), &mut out);
        out
    }

    #[test]
    fn particles_land_egocentrically_with_relative_headings() {
        let params = BeliefParams { cells: 20, ..Default::default() };
        let centre = Pose2::new(1.0, 0.7, std::f32::consts::FRAC_PI_2); // facing +y
        let ahead = Pose2::new(1.0, 1.25, std::f32::consts::FRAC_PI_2); // 0.55 m ahead, same heading
        let left = Pose2::new(0.75, 0.7, std::f32::consts::PI); // 0.25 m to the left, turned 90° left
        let out = crop(&[centre, ahead, left], &[0.5, 0.3, 0.2], centre, &params);
        let (area, n) = (400, 20);
        let weight = &out[area..2 * area];
        assert!((weight[10 * n + 10] - 0.5).abs() < 1e-6, "the centre particle sits at the crop centre");
        assert!((weight[4 * n + 10] - 0.3).abs() < 1e-6, "0.55 m ahead → 5.5 rows up, row 4");
        assert!((weight[10 * n + 7] - 0.2).abs() < 1e-6, "0.25 m left → 2.5 columns left, column 7");
        let (cos, sin) = (&out[2 * area..3 * area], &out[3 * area..]);
        assert!((cos[4 * n + 10] - 0.3).abs() < 1e-5 && sin[4 * n + 10].abs() < 1e-5, "same heading: cos");
        assert!(cos[10 * n + 7].abs() < 1e-5 && (sin[10 * n + 7] - 0.2).abs() < 1e-5, "+90°: sin");
        assert!((weight.iter().sum::<f32>() - 1.0).abs() < 1e-5, "all weight inside");
    }

    #[test]
    fn free_space_channel_shows_walls_and_the_map_edge() {
        let params = BeliefParams { cells: 40, ..Default::default() };
        // Facing +x from (0.5, 0.75): the east wall (x ∈ [1.9, 2.0]) is 1.4–1.5 m ahead.
        let out = crop(&[Pose2::new(0.5, 0.75, 0.0)], &[1.0], Pose2::new(0.5, 0.75, 0.0), &params);
        let free = &out[..1600];
        let at = |row: usize, col: usize| free[row * 40 + col];
        assert_eq!(at(20, 20), 1.0, "the robot stands in free space");
        assert_eq!(at(20 - 15, 20), 0.0, "1.45 m ahead: the east wall");
        assert_eq!(at(0, 20), 0.0, "beyond the map: not free");
    }

    #[test]
    fn particles_outside_the_crop_are_left_out() {
        let params = BeliefParams { cells: 10, ..Default::default() };
        let far = Pose2::new(1.8, 1.3, 0.0);
        let out = crop(&[Pose2::new(0.5, 0.5, 0.0), far], &[0.6, 0.4], Pose2::new(0.5, 0.5, 0.0), &params);
        assert!((out[100..200].iter().sum::<f32>() - 0.6).abs() < 1e-6, "only the near particle counts");
    }

    #[test]
    fn belief_crop_system_writes_one_crop_per_mode() {
        let mut world = World::new();
        world.insert_resource(BeliefParams { cells: 16, modes: 2, ..Default::default() });
        let map = world.spawn(room()).id();
        let poses = [Pose2::new(0.5, 0.5, 0.0), Pose2::new(1.5, 1.0, 1.0)];
        let mut set = ParticleSet::from_poses(&poses);
        set.log_w = vec![0.3f32.ln(), 0.7f32.ln()];
        let estimate = PoseEstimate { pose: Pose2::new(1.2, 0.85, 0.7), cov: Default::default() };
        let robot = world.spawn((set, estimate, OnMap(map), BeliefCrop::default())).id();
        world.run_system_once(belief_crop).expect("belief_crop runs");
        let crop = world.get::<BeliefCrop>(robot).expect("crop");
        assert_eq!(crop.values.len(), 2 * BELIEF_CHANNELS * 16 * 16, "2 modes × 4 channels × 16²");
        assert_eq!(crop.centres[0], estimate.pose, "crop 0 is centred on the estimate");
        assert!(crop.centres[1].distance(&poses[1]) < 1e-5, "crop 1 on the heavier mode: {:?}", crop.centres);
        let heavy = crop.channel(1, 1);
        assert!((heavy[8 * 16 + 8] - 0.7).abs() < 1e-6, "its particle at the centre");
    }

    #[test]
    fn the_overview_shows_the_belief_beyond_the_fine_crop_and_walls_thinner_than_its_cells() {
        let mut world = World::new();
        world.insert_resource(BeliefParams { cells: 10, overview_m: Some(0.4), ..Default::default() });
        let map = world.spawn(room()).id();
        // 1 m fine crop (±0.5 m) and 4 m overview around (1.0, 0.75) facing +x; a particle 0.8 m ahead.
        let poses = [Pose2::new(1.0, 0.75, 0.0), Pose2::new(1.8, 0.75, 0.0)];
        let mut set = ParticleSet::from_poses(&poses);
        set.log_w = vec![0.6f32.ln(), 0.4f32.ln()];
        let estimate = PoseEstimate { pose: poses[0], cov: Default::default() };
        let robot = world.spawn((set, estimate, OnMap(map), BeliefCrop::default())).id();
        world.run_system_once(belief_crop).expect("belief_crop runs");
        let crop = world.get::<BeliefCrop>(robot).expect("crop");
        assert_eq!(crop.values.len(), 2 * BELIEF_CHANNELS * 100, "the estimate's crop, then the overview");
        assert_eq!(crop.centres, vec![poses[0], poses[0]], "both on the estimate");
        let total = |mode| crop.channel(mode, 1).iter().sum::<f32>();
        assert!((total(0) - 0.6).abs() < 1e-6, "the fine crop holds the near particle only");
        assert!((total(1) - 1.0).abs() < 1e-6, "the overview holds both");
        assert!((crop.channel(1, 1)[3 * 10 + 5] - 0.4).abs() < 1e-6, "0.8 m ahead → 2 rows up, row 3");
        let partial = |mode| crop.channel(mode, 0).iter().filter(|&&f| f > 0.0 && f < 1.0).count();
        assert_eq!(partial(0), 0, "at the map's own resolution a cell is wall or free");
        assert!(partial(1) > 0, "a 0.4 m cell shows the 0.1 m walls it holds as partly occupied");
        assert!(crop.channel(1, 0).iter().all(|f| (0.0..=1.0).contains(f)));
        for side in [0.05, 1e6, f32::NAN] {
            let err = BeliefParams { overview_m: Some(side), ..Default::default() }.check().unwrap_err();
            assert!(err.contains("overview_m") && err.contains("resolution_m to 2 m"), "{err}");
        }
    }

    #[test]
    fn history_keeps_the_last_steps_crops_and_forgets_them_when_an_episode_starts() {
        let mut world = World::new();
        world.insert_resource(BeliefParams { cells: 8, history: 2, ..Default::default() });
        let map = world.spawn(room()).id();
        let at = |x: f32| {
            let pose = Pose2::new(x, 0.75, 0.0);
            (ParticleSet::from_poses(&[pose]), PoseEstimate { pose, cov: Default::default() })
        };
        let robot = world.spawn((at(0.5), OnMap(map), BeliefCrop::default())).id();
        let mut presents = vec![];
        for x in [0.5, 0.9, 1.3] {
            world.entity_mut(robot).insert(at(x));
            world.run_system_once(belief_crop).expect("belief_crop runs");
            let crop = world.get::<BeliefCrop>(robot).expect("crop");
            presents.push(crop.values[..256].to_vec());
        }
        let values = &world.get::<BeliefCrop>(robot).expect("crop").values;
        assert_eq!(values.len(), 3 * BELIEF_CHANNELS * 64, "the present and 2 past steps");
        assert_ne!(presents[1], presents[2], "the robot moved: the free-space channel changed");
        assert_eq!(&values[256..512], &presents[1][..], "one step back");
        assert_eq!(&values[512..], &presents[0][..], "two steps back");
        world.entity_mut(robot).insert((at(0.7), EpisodeStart));
        world.run_system_once(belief_crop).expect("belief_crop runs");
        let values = &world.get::<BeliefCrop>(robot).expect("crop").values;
        assert!(
            values[256..512] == values[..256] && values[512..] == values[..256],
            "a new episode has no past"
        );
    }
}
