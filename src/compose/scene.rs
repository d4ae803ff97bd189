//! Scene files (`scenes/*.ron`): the world to simulate — which maps, how many robots, the robot
//! body, episode length, physics timing and the seed. What runs on it is a schedule file's job.
//!
//! ```ron
//! Scene(maps: Procedural(split: seen, count: 2), robots_per_map: 4, seed: 7)
//! ```

use crate::act::PhysicsParams;
use crate::compose::error::{ComposeError, read_ron};
use crate::compose::paths::relative_to_file;
use crate::episode::EpisodeParams;
use crate::world::map::load_ros_map;
use crate::world::map::procedural::{ApartmentParams, Split, generate_apartment};
use crate::world::{OccupancyMap, RobotParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Which maps to load; each map gets its own physics world.
    pub maps: MapSource,
    /// Robots spawned on every map (batched through every system in one pass).
    #[serde(default = "one")]
    pub robots_per_map: usize,
    /// Whether robots sharing a map are obstacles to each other's bodies (their LiDARs see each
    /// other when the schedule's `lidar` step sets `robots_block: true`).
    #[serde(default)]
    pub robots_collide: bool,
    /// Root of every random stream of the run.
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub episode: EpisodeParams,
    #[serde(default)]
    pub robot: RobotParams,
    #[serde(default)]
    pub physics: PhysicsParams,
    /// Schedule to run when the command line names none, relative to this file.
    #[serde(default)]
    pub systems: Option<PathBuf>,
}

fn one() -> usize {
    1
}

/// True for finite numbers above zero (NaN is not).
fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

/// Where the maps come from.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum MapSource {
    /// `count` procedural apartments from the `split`'s seed range, starting `first` seeds in.
    Procedural {
        split: Split,
        #[serde(default)]
        first: u64,
        #[serde(default = "one")]
        count: usize,
        #[serde(default)]
        params: ApartmentParams,
    },
    /// ROS map_server YAML files, relative to the scene file (as map_server resolves images):
    /// `Ros(path: "office.yaml")` for one map (the spelling eval configs use too), or
    /// `Ros(paths: ["a.yaml", "b.yaml"])` for several.
    Ros {
        #[serde(default, deserialize_with = "some_path")]
        path: Option<PathBuf>,
        #[serde(default)]
        paths: Vec<PathBuf>,
    },
}

/// `path: "a.yaml"` rather than RON's `path: Some("a.yaml")`: the field is optional only so that
/// `paths` can stand in for it.
pub fn some_path<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Option<PathBuf>, D::Error> {
    PathBuf::deserialize(de).map(Some)
}

/// A map ready to spawn, with the name results are filed under.
#[derive(Clone, Debug)]
pub struct NamedMap {
    pub name: String,
    pub map: OccupancyMap,
}

/// A validated scene with its maps loaded.
#[derive(Clone, Debug)]
pub struct LoadedScene {
    pub path: PathBuf,
    pub scene: Scene,
    pub maps: Vec<NamedMap>,
}

impl Scene {
    /// A scene in code: `count` procedural apartments of `split` from its `first` seed on,
    /// `robots_per_map` robots each, everything else at its default (change fields as needed).
    pub fn apartments(split: Split, first: u64, count: usize, robots_per_map: usize) -> Scene {
        Scene {
            maps: MapSource::Procedural { split, first, count, params: ApartmentParams::default() },
            robots_per_map,
            robots_collide: false,
            seed: 0,
            episode: EpisodeParams::default(),
            robot: RobotParams::default(),
            physics: PhysicsParams::default(),
            systems: None,
        }
    }

    /// Reads, validates and loads a scene file and its maps.
    pub fn load(path: &Path) -> Result<LoadedScene, ComposeError> {
        read_ron::<Scene>(path)?.into_loaded(path)
    }

    /// Validates an in-code scene and loads its maps; `path` labels errors and anchors relative paths.
    pub fn into_loaded(self, path: &Path) -> Result<LoadedScene, ComposeError> {
        let invalid = |field: &str, message: &str| ComposeError::Scene {
            path: path.to_owned(),
            field: field.to_owned(),
            message: message.to_owned(),
        };
        if self.robots_per_map == 0 {
            return Err(invalid("robots_per_map", "expected at least 1 robot per map"));
        }
        if self.episode.steps == 0 {
            return Err(invalid("episode.steps", "expected at least 1 step per episode"));
        }
        if self.physics.substeps == 0 || !positive(self.physics.dt_s) {
            return Err(invalid("physics", "expected substeps ≥ 1 and dt_s > 0"));
        }
        if !positive(self.robot.radius_m) {
            return Err(invalid("robot.radius_m", "expected a positive radius in metres"));
        }
        if let MapSource::Procedural { params, .. } = &self.maps
            && let Err(e) = params.validate()
        {
            let field = format!("maps.params.{}", e.field);
            return Err(invalid(&field, &format!("expected {}, got {}", e.expected, e.got)));
        }
        if let MapSource::Ros { path: Some(_), paths } = &self.maps
            && !paths.is_empty()
        {
            return Err(invalid("maps", "expected `path` (one map) or `paths` (several), not both"));
        }
        let maps = match &self.maps {
            _ if self.map_count() == 0 => return Err(invalid("maps", "expected at least one map")),
            MapSource::Procedural { split, first, count, params } => (0..*count as u64)
                .map(|k| {
                    let seed = split.seeds().start + first + k;
                    NamedMap { name: format!("apartment_{seed}"), map: generate_apartment(seed, params) }
                })
                .collect(),
            MapSource::Ros { path: one, paths } => one
                .iter()
                .chain(paths)
                .map(|p| {
                    let map = load_ros_map(&relative_to_file(path, p))
                        .map_err(|e| invalid("maps", &e.to_string()))?;
                    let name =
                        p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into());
                    Ok(NamedMap { name, map })
                })
                .collect::<Result<_, ComposeError>>()?,
        };
        Ok(LoadedScene { path: path.to_owned(), scene: self, maps })
    }

    fn map_count(&self) -> usize {
        match &self.maps {
            MapSource::Procedural { count, .. } => *count,
            MapSource::Ros { path, paths } => usize::from(path.is_some()) + paths.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use crate::world::map::save_ros_map;

    /// A scene file beside two saved copies of the tiny room, with `maps` spelled as given.
    fn load_with(maps: &str) -> Result<LoadedScene, ComposeError> {
        let dir = tempfile::tempdir().expect("temp dir");
        std::fs::create_dir(dir.path().join("maps")).expect("maps folder");
        for name in ["a", "b"] {
            save_ros_map(&tiny_room(), &dir.path().join(format!("maps/{name}.yaml"))).expect("save map");
        }
        let scene = dir.path().join("scene.ron");
        std::fs::write(&scene, format!("Scene(maps: {maps})")).expect("write scene");
        Scene::load(&scene)
    }

    #[test]
    fn ros_maps_take_path_or_paths_relative_to_the_scene() {
        let one = load_with(r#"Ros(path: "maps/a.yaml")"#).expect("`path`, as eval configs spell it");
        assert_eq!(one.maps.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(), ["a"]);
        let two = load_with(r#"Ros(paths: ["maps/a.yaml", "./maps/../maps/b.yaml"])"#).expect("`paths`");
        assert_eq!(two.maps.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(), ["a", "b"]);
    }

    #[test]
    fn ros_maps_reject_both_spellings_at_once_and_none() {
        let both = load_with(r#"Ros(path: "maps/a.yaml", paths: ["maps/b.yaml"])"#).expect_err("both");
        assert!(both.to_string().contains("not both"), "{both}");
        let none = load_with("Ros()").expect_err("no map");
        assert!(none.to_string().contains("at least one map"), "{none}");
    }
}
