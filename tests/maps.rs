//! The real ROS maps in `../shared/maps` load with the sizes, resolutions and origins their YAMLs
//! state, yield traversable space and plannable paths; broken map files give the right
//! `MapError`. Skips (with a message) when `../shared/maps` is absent, as in a fresh clone.

use apfn::world::map::{
    Cell, DistanceField, MapError, NetworkMap, OccupancyMap, TraversableMap, load_ros_map, plan_path,
    save_ros_map,
};
use apfn::world::{Pose2, RobotParams};
use std::path::{Path, PathBuf};

fn shared_maps() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/maps");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {} not found (real ROS maps live beside the project)", dir.display());
        None
    }
}

/// name, (width, height), resolution, origin, bounds on (free, occupied, unknown) fractions.
struct Expected {
    name: &'static str,
    size: (usize, usize),
    resolution_m: f32,
    origin: Pose2,
    free: (f32, f32),
    occupied: (f32, f32),
    unknown: (f32, f32),
}

const EXPECTED: [Expected; 4] = [
    Expected {
        name: "nav2_depot",
        size: (604, 307),
        resolution_m: 0.05,
        origin: Pose2::new(0.0, 0.0, 0.0),
        free: (0.9, 0.99),
        occupied: (0.01, 0.1),
        unknown: (0.0, 0.0),
    },
    Expected {
        name: "nav2_warehouse",
        size: (1006, 1674),
        resolution_m: 0.03,
        origin: Pose2::new(-15.1, -25.0, 0.0),
        free: (0.75, 0.95),
        occupied: (0.005, 0.05),
        unknown: (0.05, 0.25),
    },
    Expected {
        name: "nav2_turtlebot3_world",
        size: (384, 384),
        resolution_m: 0.05,
        origin: Pose2::new(-10.0, -10.0, 0.0),
        free: (0.02, 0.15),
        occupied: (0.001, 0.03),
        unknown: (0.85, 0.98),
    },
    Expected {
        name: "aws_small_house",
        size: (500, 500),
        resolution_m: 0.05,
        origin: Pose2::new(-12.5, -12.5, 0.0),
        free: (0.15, 0.35),
        occupied: (0.005, 0.05),
        unknown: (0.65, 0.8),
    },
];

fn fractions(map: &OccupancyMap) -> (f32, f32, f32) {
    let (f, o, u) = map.counts();
    let n = map.cells.len() as f32;
    (f as f32 / n, o as f32 / n, u as f32 / n)
}

#[test]
fn every_shared_map_loads_with_its_yaml_geometry() {
    let Some(dir) = shared_maps() else { return };
    for e in &EXPECTED {
        let map = load_ros_map(&dir.join(format!("{}.yaml", e.name)))
            .unwrap_or_else(|err| panic!("{} must load: {err}", e.name));
        assert_eq!((map.width, map.height), e.size, "{}: size in pixels", e.name);
        assert_eq!(map.resolution_m, e.resolution_m, "{}: resolution", e.name);
        assert_eq!(map.origin, e.origin, "{}: origin", e.name);
        let (f, o, u) = fractions(&map);
        eprintln!("{}: free {f:.3} occupied {o:.3} unknown {u:.3}", e.name);
        let within = |v: f32, (lo, hi): (f32, f32)| v >= lo && v <= hi;
        assert!(within(f, e.free), "{}: free fraction {f} outside {:?}", e.name, e.free);
        assert!(within(o, e.occupied), "{}: occupied fraction {o} outside {:?}", e.name, e.occupied);
        assert!(within(u, e.unknown), "{}: unknown fraction {u} outside {:?}", e.name, e.unknown);
    }
}

#[test]
fn every_shared_map_has_traversable_space_and_layers() {
    let Some(dir) = shared_maps() else { return };
    let radius = RobotParams::default().radius_m;
    for e in &EXPECTED {
        let map = load_ros_map(&dir.join(format!("{}.yaml", e.name))).expect("loads");
        let trav = TraversableMap::build(&map, radius).expect("a robot fits somewhere");
        let area = trav.area_m2(map.resolution_m);
        let free_area = map.counts().0 as f32 * map.resolution_m * map.resolution_m;
        eprintln!("{}: traversable {area:.1} m² of {free_area:.1} m² free", e.name);
        assert!(area > 1.0 && area < free_area, "{}: traversable area {area} m²", e.name);
        for &(i, j) in trav.cells.iter().step_by(97) {
            assert_eq!(map.get(i as usize, j as usize), Cell::Free, "{}: traversable cells are free", e.name);
        }

        let net = NetworkMap::from_fine(&map, 0.1);
        let (w_m, h_m) = map.size_m();
        assert_eq!(net.width, (w_m / 0.1 - 1e-3).ceil() as usize, "{}: network width", e.name);
        assert_eq!(net.height, (h_m / 0.1 - 1e-3).ceil() as usize, "{}: network height", e.name);
        assert!(net.occupancy.iter().all(|o| (0.0..=1.0).contains(o)), "{}: fractions", e.name);

        let field = DistanceField::build(&map);
        let (i, j) = trav.cells[trav.cells.len() / 2];
        let (x, y) = map.cell_center(i as usize, j as usize);
        let d = field.distance_at(&map, x, y);
        assert!(d > 0.0 && d < 50.0, "{}: distance to the nearest wall {d} m", e.name);
    }
}

#[test]
fn warehouse_plans_across_the_map() {
    let Some(dir) = shared_maps() else { return };
    let map = load_ros_map(&dir.join("nav2_warehouse.yaml")).expect("loads");
    let trav = TraversableMap::build(&map, RobotParams::default().radius_m).expect("traversable");
    // The traversable cells farthest apart along y: a path spanning most of the warehouse.
    let low = *trav.cells.iter().min_by_key(|c| (c.1, c.0)).expect("cells");
    let high = *trav.cells.iter().max_by_key(|c| (c.1, c.0)).expect("cells");
    let start = map.cell_center(low.0 as usize, low.1 as usize);
    let goal = map.cell_center(high.0 as usize, high.1 as usize);
    let path = plan_path(&trav, &map, start, goal).expect("one connected component: a path exists");
    let length: f32 = path.windows(2).map(|s| (s[1].0 - s[0].0).hypot(s[1].1 - s[0].1)).sum();
    let straight = (goal.0 - start.0).hypot(goal.1 - start.1);
    eprintln!("warehouse path: {} cells, {length:.1} m, straight {straight:.1} m", path.len());
    assert!(length >= straight - 1e-3, "a path cannot beat the straight line");
    assert!(straight > 20.0, "start and goal are far apart ({straight} m)");
}

#[test]
fn shared_map_survives_export_and_import() {
    let Some(dir) = shared_maps() else { return };
    let map = load_ros_map(&dir.join("aws_small_house.yaml")).expect("loads");
    let out = tempfile::tempdir().expect("temp dir");
    let yaml = out.path().join("house.yaml");
    save_ros_map(&map, &yaml).expect("export");
    assert_eq!(load_ros_map(&yaml).expect("re-import"), map, "export → import is lossless");
}

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
}

const GOOD_YAML: &str = "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";

#[test]
fn broken_yaml_reports_file_and_location() {
    let dir = tempfile::tempdir().expect("temp dir");
    let yaml = dir.path().join("broken.yaml");
    write(&yaml, "image: m.pgm\nresolution: [0.05\norigin: [0, 0, 0]\n");
    match load_ros_map(&yaml) {
        Err(err @ MapError::YamlParse { .. }) => {
            let MapError::YamlParse { ref path, line, .. } = err else { unreachable!() };
            assert_eq!(path, &yaml, "names the YAML");
            assert!(line >= 2, "points at the broken line, got {line}");
            assert!(err.to_string().contains("broken.yaml"), "message names the file: {err}");
        }
        other => panic!("expected YamlParse, got {other:?}"),
    }
    let missing = dir.path().join("absent.yaml");
    assert!(
        matches!(load_ros_map(&missing), Err(MapError::YamlUnreadable { ref path, .. }) if path == &missing),
        "a missing YAML is named"
    );
}

#[test]
fn missing_or_corrupt_image_is_named() {
    let dir = tempfile::tempdir().expect("temp dir");
    let yaml = dir.path().join("m.yaml");
    write(&yaml, GOOD_YAML);
    match load_ros_map(&yaml) {
        Err(err @ MapError::ImageMissing { .. }) => {
            assert!(err.to_string().contains("m.pgm") && err.to_string().contains("m.yaml"), "{err}");
        }
        other => panic!("expected ImageMissing, got {other:?}"),
    }
    write(&dir.path().join("m.pgm"), "P5\n4 4\n255\nxy");
    match load_ros_map(&yaml) {
        Err(MapError::ImageUnreadable { path, .. }) => assert_eq!(path, dir.path().join("m.pgm")),
        other => panic!("expected ImageUnreadable for a truncated PGM, got {other:?}"),
    }
}

#[test]
fn map_without_free_space_is_rejected() {
    let dir = tempfile::tempdir().expect("temp dir");
    let yaml = dir.path().join("m.yaml");
    write(&yaml, GOOD_YAML);
    let mut pgm = b"P5\n3 2\n255\n".to_vec();
    pgm.extend([0, 205, 0, 205, 0, 0]);
    std::fs::write(dir.path().join("m.pgm"), pgm).expect("write pgm");
    match load_ros_map(&yaml) {
        Err(err @ MapError::NoFreeSpace { .. }) => {
            assert!(err.to_string().contains("m.yaml"), "names the file: {err}");
        }
        other => panic!("expected NoFreeSpace, got {other:?}"),
    }
}

#[test]
fn inspect_prints_the_yaml_geometry_of_a_real_map() {
    let Some(dir) = shared_maps() else { return };
    let v = apfn::cli::map::inspect(&dir.join("nav2_turtlebot3_world.yaml")).expect("inspect");
    assert_eq!((v["width"].as_u64(), v["height"].as_u64()), (Some(384), Some(384)), "{v}");
    let origin: Vec<f64> =
        v["origin"].as_array().expect("origin list").iter().filter_map(|x| x.as_f64()).collect();
    assert_eq!(origin, vec![-10.0, -10.0, 0.0], "{v}");
    let sum: f64 = ["free_fraction", "occupied_fraction", "unknown_fraction"]
        .iter()
        .map(|k| v[*k].as_f64().expect("fraction"))
        .sum();
    assert!((sum - 1.0).abs() < 1e-9, "fractions sum to 1: {v}");
    assert!(v["traversable_area_m2"].as_f64().expect("area") > 1.0, "{v}");
}
