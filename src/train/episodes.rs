//! Training data for PF-net: short episodes of a policy driving on procedural apartments,
//! simulated with the same systems as every other run (a schedule file), recorded per step as
//! the true pose, the odometry, the 56 × 56 LiDAR grid (stored as u8) and, when the schedule runs
//! the `depth` step, the depth strip.
//!
//! Timing as in `apfn record`: after agent step k, `PreviousPose` is the pose the step's scan
//! (and so its grid) was taken from, and `Odometry.delta` is the motion since the previous scan.

use crate::compose::{LoadedScene, MapName, Pipeline};
use crate::episode::Episode;
use crate::plugin::headless_app;
use crate::sense::{DepthStrip, LocalGrid, Odometry};
use crate::world::map::NetworkMap;
use crate::world::{OnMap, Pose2, PreviousPose};
use anyhow::{Context, bail};
use std::collections::HashMap;

/// One recorded episode.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedEpisode {
    /// Index into [`EpisodeSet::maps`].
    pub map: usize,
    /// True pose at each step's scan.
    pub poses: Vec<Pose2>,
    /// Motion since the previous step's scan (identity at step 0).
    pub odometry: Vec<Pose2>,
    /// The grids, `steps × cells²` values of 0…255 (value / 255 is the network's input).
    pub grids: Vec<u8>,
    /// The wide grids, as `grids` (empty unless `local_grid` has a `wide_extent_m`).
    pub wide_grids: Vec<u8>,
    /// The depth strips, `steps × columns` metres (empty without the `depth` step).
    pub depths: Vec<f32>,
}

/// Episodes and the network maps they were driven on.
#[derive(Clone, Debug, Default)]
pub struct EpisodeSet {
    pub maps: Vec<NetworkMap>,
    /// The scene's names of those maps (`apartment_<seed>` for procedural ones).
    pub map_names: Vec<String>,
    pub episodes: Vec<RecordedEpisode>,
    /// Side of a grid, cells.
    pub grid_cells: usize,
    /// Columns of a depth strip (0: none recorded).
    pub depth_columns: usize,
    /// Window of the wide grids, metres (none recorded: `None`).
    pub wide_extent_m: Option<f32>,
}

impl EpisodeSet {
    /// Steps per episode.
    pub fn steps(&self) -> usize {
        self.episodes.first().map_or(0, |e| e.poses.len())
    }

    /// Appends `other`'s maps and episodes (its episodes then index the appended maps).
    pub fn extend(&mut self, other: EpisodeSet) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.episodes.is_empty()
                || (other.grid_cells, other.depth_columns, other.wide_extent_m, other.steps())
                    == (self.grid_cells, self.depth_columns, self.wide_extent_m, self.steps()),
            "episode sets differ in grid side, depth columns, wide window or steps: {:?} against {:?}",
            (other.grid_cells, other.depth_columns, other.wide_extent_m, other.steps()),
            (self.grid_cells, self.depth_columns, self.wide_extent_m, self.steps())
        );
        let offset = self.maps.len();
        self.maps.extend(other.maps);
        self.map_names.extend(other.map_names);
        self.episodes
            .extend(other.episodes.into_iter().map(|e| RecordedEpisode { map: e.map + offset, ..e }));
        (self.grid_cells, self.depth_columns, self.wide_extent_m) =
            (other.grid_cells, other.depth_columns, other.wide_extent_m);
        Ok(())
    }
}

/// Simulates `scene` under `pipeline` until `count` complete episodes are recorded (robots in
/// spawn order, episodes in the order they finish: deterministic for the scene's seed).
/// `after_step` is called once per agent step (progress bars).
pub fn simulate_episodes(
    scene: &LoadedScene,
    pipeline: Pipeline,
    count: usize,
    mut after_step: impl FnMut(usize),
) -> anyhow::Result<EpisodeSet> {
    let names = pipeline.names();
    for needed in ["episode_reset", "odometry", "local_grid"] {
        if !names.contains(&needed) {
            bail!(
                "schedule {} has no `{needed}` step; recording PF-net episodes needs it",
                pipeline.source.display()
            );
        }
    }
    let steps = scene.scene.episode.steps as usize;
    let (mut app, robots) = headless_app(scene, pipeline)?;
    let world = app.world_mut();
    let mut map_index = HashMap::new();
    let (mut maps, mut map_names) = (Vec::new(), Vec::new());
    for (entity, map, name) in world.query::<(bevy::prelude::Entity, &NetworkMap, &MapName)>().iter(world) {
        map_index.insert(entity, maps.len());
        maps.push(map.clone());
        map_names.push(name.0.clone());
    }
    let mut current: Vec<Option<RecordedEpisode>> = vec![None; robots.len()];
    let mut done = EpisodeSet {
        maps,
        map_names,
        episodes: Vec::with_capacity(count),
        grid_cells: 0,
        depth_columns: 0,
        wide_extent_m: None,
    };
    let to_byte = |v: &f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    while done.episodes.len() < count {
        app.update();
        let world = app.world();
        for (slot, &robot) in current.iter_mut().zip(&robots) {
            let step = world.get::<Episode>(robot).context("a robot without Episode")?.step as usize;
            let grid = world.get::<LocalGrid>(robot).context("a robot without LocalGrid")?;
            let map = map_index[&world.get::<OnMap>(robot).context("a robot without OnMap")?.0];
            if step == 1 {
                *slot = Some(RecordedEpisode {
                    map,
                    poses: vec![],
                    odometry: vec![],
                    grids: vec![],
                    wide_grids: vec![],
                    depths: vec![],
                });
            }
            let Some(episode) = slot.as_mut() else { continue }; // joined mid-episode
            episode.poses.push(world.get::<PreviousPose>(robot).context("no PreviousPose")?.0);
            let delta = world.get::<Odometry>(robot).context("no Odometry")?.delta;
            episode.odometry.push(if step == 1 { Pose2::default() } else { delta });
            episode.grids.extend(grid.values.iter().map(to_byte));
            done.grid_cells = grid.cells;
            if let Some(wide) = &grid.wide {
                episode.wide_grids.extend(wide.values.iter().map(to_byte));
            }
            done.wide_extent_m = grid.wide.as_ref().map(|wide| wide.extent_m);
            // Robots carry an empty strip unless the schedule runs `depth`.
            let depths = world.get::<DepthStrip>(robot).map_or(&[][..], |strip| &strip.depths_m);
            episode.depths.extend_from_slice(depths);
            done.depth_columns = depths.len();
            if step == steps && done.episodes.len() < count {
                done.episodes.push(slot.take().expect("recording"));
            }
        }
        after_step(done.episodes.len());
    }
    Ok(done)
}
