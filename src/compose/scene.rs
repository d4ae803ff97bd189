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
use crate::limits::{
    EPISODE_STEPS, MAPS, PHYSICS_SUBSTEPS, ROBOTS_PER_MAP, ROBOTS_PER_WORLD, SCENE_MAP_CELLS, thousands,
};
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
        // Counts first: nothing below may allocate per map or per robot before they are sane.
        let maps = self.map_count();
        for (field, limit, n) in [
            ("maps", MAPS, maps),
            ("robots_per_map", ROBOTS_PER_MAP, self.robots_per_map),
            ("robots_per_map", ROBOTS_PER_WORLD, maps.saturating_mul(self.robots_per_map)),
            ("episode.steps", EPISODE_STEPS, self.episode.steps as usize),
            ("physics.substeps", PHYSICS_SUBSTEPS, self.physics.substeps as usize),
        ] {
            if !limit.contains(n) {
                return Err(invalid(field, &format!("expected {}, got {n}", limit.expected)));
            }
        }
        if !positive(self.physics.dt_s) {
            return Err(invalid("physics.dt_s", "expected a time step > 0 s"));
        }
        if !positive(self.robot.radius_m) {
            return Err(invalid("robot.radius_m", "expected a positive radius in metres"));
        }
        if let MapSource::Procedural { split, first, count, .. } = &self.maps
            && first.saturating_add(*count as u64) > split.seeds().end - split.seeds().start
        {
            let size = split.seeds().end - split.seeds().start;
            let message = format!(
                "expected first + count ≤ {} (the split's seeds), got {first} + {count}",
                thousands(size)
            );
            return Err(invalid("maps.first", &message));
        }
        if let MapSource::Procedural { params, .. } = &self.maps
            && let Err(e) = params.validate()
        {
            let field = format!("maps.params.{}", e.field);
            return Err(invalid(&field, &format!("expected {}, got {}", e.expected, e.got)));
        }
        if let MapSource::Procedural { count, params, .. } = &self.maps {
            let side_cells =
                f64::from((params.max_side_m + 2.0 * params.margin_m) / params.resolution_m).ceil();
            let cells = *count as f64 * side_cells * side_cells;
            if cells > SCENE_MAP_CELLS as f64 {
                let message = format!(
                    "expected at most {} map cells in all (count × ((max_side_m + 2·margin_m) / resolution_m)²), got {count} × {side_cells}²",
                    thousands(SCENE_MAP_CELLS)
                );
                return Err(invalid("maps", &message));
            }
        }
        if let MapSource::Ros { path: Some(_), paths } = &self.maps
            && !paths.is_empty()
        {
            return Err(invalid("maps", "expected `path` (one map) or `paths` (several), not both"));
        }
        let maps = match &self.maps {
            MapSource::Procedural { split, first, count, params } => (0..*count as u64)
                .map(|k| {
                    let seed = split.seeds().start + first + k;
                    NamedMap { name: format!("apartment_{seed}"), map: generate_apartment(seed, params) }
                })
                .collect(),
            MapSource::Ros { path: one, paths } => {
                let mut maps = Vec::new();
                let mut cells = 0;
                for p in one.iter().chain(paths) {
                    let map = load_ros_map(&relative_to_file(path, p))
                        .map_err(|e| invalid("maps", &e.to_string()))?;
                    // Each image's size was checked before decoding; this bounds their sum.
                    cells += map.cells.len() as u64;
                    if cells > SCENE_MAP_CELLS {
                        let message =
                            format!("expected at most {} map cells in all", thousands(SCENE_MAP_CELLS));
                        return Err(invalid("maps", &message));
                    }
                    let name =
                        p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into());
                    maps.push(NamedMap { name, map });
                }
                maps
            }
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

    /// The error of loading `Scene(<fields>)` from a file `huge.ron`, and that file's path.
    fn scene_error(fields: &str) -> (String, PathBuf) {
        let dir = tempfile::tempdir().expect("temp dir");
        let scene = dir.path().join("huge.ron");
        std::fs::write(&scene, format!("Scene({fields})")).expect("write scene");
        (Scene::load(&scene).expect_err("out of range").to_string(), scene)
    }

    #[test]
    fn scene_counts_are_bounded_before_anything_is_allocated() {
        let (e, path) = scene_error("maps: Procedural(split: seen, count: 1), robots_per_map: 100000000");
        let want = "field `robots_per_map`: expected 1 to 1,000 robots per map, got 100000000";
        assert_eq!(e, format!("{}: {want}", path.display()));
        let (e, _) = scene_error("maps: Procedural(split: seen, count: 20), robots_per_map: 1000");
        assert!(
            e.ends_with("expected 1 to 10,000 robots in a world (maps × robots_per_map), got 20000"),
            "{e}"
        );
        let (e, _) = scene_error("maps: Procedural(split: seen, count: 5000)");
        assert!(e.ends_with("field `maps`: expected 1 to 1,000 maps, got 5000"), "{e}");
        let (e, _) = scene_error("maps: Procedural(split: seen), episode: (steps: 4000000000)");
        assert!(
            e.ends_with("field `episode.steps`: expected 1 to 100,000 steps per episode, got 4000000000"),
            "{e}"
        );
        let (e, _) = scene_error("maps: Procedural(split: seen, first: 999999, count: 2)");
        assert!(
            e.ends_with(
                "field `maps.first`: expected first + count ≤ 1,000,000 (the split's seeds), got 999999 + 2"
            ),
            "{e}"
        );
        let big = "maps: Procedural(split: seen, count: 16, params: (min_side_m: 5.0, max_side_m: 100, max_rooms: 5))";
        let (e, _) = scene_error(big);
        assert!(e.contains("field `maps`: expected at most 50,000,000 map cells in all"), "{e}");
        let (e, _) = scene_error("maps: Procedural(split: seen), physics: (substeps: 0)");
        assert!(e.contains("field `physics.substeps`: expected 1 to 100"), "{e}");
    }

    #[test]
    fn ros_maps_reject_both_spellings_at_once_and_none() {
        let both = load_with(r#"Ros(path: "maps/a.yaml", paths: ["maps/b.yaml"])"#).expect_err("both");
        assert!(both.to_string().contains("not both"), "{both}");
        let none = load_with("Ros()").expect_err("no map");
        assert!(none.to_string().contains("expected 1 to 1,000 maps, got 0"), "{none}");
    }
}
