//! `apfn map …`: inspect a ROS map, render a map to PNG, export procedural apartments as ROS maps,
//! resample a map to a coarser resolution.

use crate::world::RobotParams;
use crate::world::map::procedural::{ApartmentParams, generate_apartment};
use crate::world::map::{CoarsenRule, TraversableMap, load_ros_map, render, save_ros_map, write_atomically};
use anyhow::{Context, bail, ensure};
use image::ImageFormat;
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// Map tools: look at, draw and export occupancy maps.
#[derive(clap::Subcommand, Clone, Debug, PartialEq)]
pub enum MapCommand {
    /// Print one JSON object describing a ROS map: size in cells, resolution (m/cell), origin
    /// [x, y, yaw], free/occupied/unknown fractions and the area (m²) a default robot can reach.
    Inspect {
        /// The map's YAML file (ROS map_server format).
        path: PathBuf,
    },
    /// Draw a map as a PNG, one pixel per cell, north up: free white, occupied black, unknown
    /// grey, space a default robot can reach tinted light blue.
    Render {
        /// A ROS map YAML to draw (or use --procedural).
        path: Option<PathBuf>,
        /// Draw the procedural apartment with this seed instead of a file.
        #[arg(long)]
        procedural: Option<u64>,
        /// The PNG file to write (its name must end in .png).
        #[arg(long)]
        out: PathBuf,
    },
    /// Write the procedural apartment with this seed as a ROS map:
    /// `<out>/apartment_<seed>.yaml` and `.pgm`.
    Export {
        /// Seed of the procedural apartment.
        #[arg(long)]
        procedural: u64,
        /// Folder to write into (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Cell size, metres (default: the generator's 0.05; older ROS maps are 0.1).
        #[arg(long)]
        resolution: Option<f32>,
    },
    /// Write a ROS map at a coarser resolution, unknown areas kept, as `<out>` and the PGM beside it.
    Resample {
        /// The map's YAML file (ROS map_server format).
        path: PathBuf,
        /// The new cell size, metres (at least the map's own).
        #[arg(long)]
        resolution: f32,
        /// keep_walls: as a mapper at that resolution would draw it; average_image: as shrinking the
        /// PGM and reading it back would (thin walls beside unknown space become unknown).
        #[arg(long, value_enum, default_value = "keep_walls")]
        rule: CoarsenRule,
        /// The YAML file to write (its folder is created if missing).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs one `apfn map` subcommand.
pub fn run(cmd: MapCommand) -> anyhow::Result<()> {
    match cmd {
        MapCommand::Inspect { path } => {
            println!("{}", inspect(&path)?);
        }
        MapCommand::Render { path, procedural, out } => {
            ensure!(
                out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")),
                "--out {}: map render writes PNG only; expected a file name ending in .png",
                out.display()
            );
            let map = match (path, procedural) {
                (Some(path), None) => load_ros_map(&path)?,
                (None, Some(seed)) => generate_apartment(seed, &ApartmentParams::default()),
                _ => bail!("render needs exactly one of a map YAML path or --procedural <seed>"),
            };
            let trav = TraversableMap::build(&map, RobotParams::default().radius_m)
                .inspect_err(|e| eprintln!("warning: drawing without traversable tint: {e}"))
                .ok();
            let mut png = Vec::new();
            render(&map, trav.as_ref())
                .write_to(&mut Cursor::new(&mut png), ImageFormat::Png)
                .context("encoding the PNG")?;
            write_atomically(&out, &png)?;
            println!(
                "wrote {} ({} × {} pixels, one per {} m cell)",
                out.display(),
                map.width,
                map.height,
                map.resolution_m
            );
        }
        MapCommand::Export { procedural, out, resolution } => {
            let defaults = ApartmentParams::default();
            let params =
                ApartmentParams { resolution_m: resolution.unwrap_or(defaults.resolution_m), ..defaults };
            params.validate().map_err(|e| anyhow::anyhow!("--resolution: {e}"))?;
            let map = generate_apartment(procedural, &params);
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let yaml = out.join(format!("apartment_{procedural}.yaml"));
            save_ros_map(&map, &yaml)?;
            println!("wrote {} and {}", yaml.display(), yaml.with_extension("pgm").display());
        }
        MapCommand::Resample { path, resolution, rule, out } => {
            let map = load_ros_map(&path)?;
            ensure!(
                resolution.is_finite() && resolution >= map.resolution_m,
                "--resolution {resolution}: expected a cell size ≥ the map's {} m ({})",
                map.resolution_m,
                path.display()
            );
            if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
            }
            save_ros_map(&map.coarsened(resolution, rule), &out)?;
            println!("wrote {} and {}", out.display(), out.with_extension("pgm").display());
        }
    }
    Ok(())
}

/// The summary `inspect` prints.
pub fn inspect(path: &Path) -> anyhow::Result<serde_json::Value> {
    let map = load_ros_map(path)?;
    let (free, occupied, unknown) = map.counts();
    let n = map.cells.len().max(1) as f64;
    let trav = TraversableMap::build(&map, RobotParams::default().radius_m);
    let area = trav.map_or(0.0, |t| t.area_m2(map.resolution_m));
    let o = map.origin;
    Ok(serde_json::json!({
        "width": map.width,
        "height": map.height,
        "resolution": shortest(map.resolution_m),
        "origin": [shortest(o.x), shortest(o.y), shortest(o.yaw)],
        "free_fraction": round6(free as f64 / n),
        "occupied_fraction": round6(occupied as f64 / n),
        "unknown_fraction": round6(unknown as f64 / n),
        "traversable_area_m2": round6(area as f64),
    }))
}

/// The f32 as the shortest decimal that reads back to it (0.05, not 0.05000000074505806).
fn shortest(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(x as f64)
}

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use crate::world::Cell;
    use clap::Parser;
    use image::Rgb;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        cmd: MapCommand,
    }

    #[test]
    fn subcommands_parse() {
        let cli =
            Cli::try_parse_from(["apfn", "render", "--procedural", "3", "--out", "a.png"]).expect("parses");
        assert_eq!(cli.cmd, MapCommand::Render { path: None, procedural: Some(3), out: "a.png".into() });
        let cli = Cli::try_parse_from(["apfn", "export", "--procedural", "9", "--out", "d"]).expect("parses");
        assert_eq!(cli.cmd, MapCommand::Export { procedural: 9, out: "d".into(), resolution: None });
        assert!(Cli::try_parse_from(["apfn", "export", "--out", "d"]).is_err(), "export needs a seed");
    }

    #[test]
    fn inspect_reports_geometry_and_fractions() {
        let dir = tempfile::tempdir().expect("temp dir");
        let yaml = dir.path().join("room.yaml");
        save_ros_map(&tiny_room(), &yaml).expect("save");
        let v = inspect(&yaml).expect("inspect");
        assert_eq!((v["width"].as_u64(), v["height"].as_u64()), (Some(20), Some(15)), "{v}");
        assert!((v["resolution"].as_f64().unwrap_or(0.0) - 0.1).abs() < 1e-6, "{v}");
        let (f, o, u) = tiny_room().counts();
        let total = (f + o + u) as f64;
        assert!((v["free_fraction"].as_f64().unwrap_or(-1.0) - f as f64 / total).abs() < 1e-9, "{v}");
        assert!((v["occupied_fraction"].as_f64().unwrap_or(-1.0) - o as f64 / total).abs() < 1e-9, "{v}");
        assert_eq!(v["unknown_fraction"].as_f64(), Some(0.0), "{v}");
        let area = v["traversable_area_m2"].as_f64().unwrap_or(0.0);
        assert!(area > 0.1 && area < f as f64 * 0.01, "traversable area {area} m² below free area");
    }

    #[test]
    fn render_writes_a_north_up_png() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut map = tiny_room();
        map.set(1, 13, Cell::Unknown); // top-left inside corner
        let yaml = dir.path().join("room.yaml");
        save_ros_map(&map, &yaml).expect("save");
        let out = dir.path().join("room.png");
        run(MapCommand::Render { path: Some(yaml), procedural: None, out: out.clone() }).expect("render");
        let img = image::open(&out).expect("a readable PNG").to_rgb8();
        assert_eq!(img.dimensions(), (20, 15), "one pixel per cell");
        assert_eq!(img.get_pixel(0, 0), &Rgb([0, 0, 0]), "wall corner is black");
        assert_eq!(img.get_pixel(1, 1), &Rgb([150, 150, 150]), "row 0 is the map's top: unknown at (1, 13)");
        assert_eq!(img.get_pixel(1, 7), &Rgb([255, 255, 255]), "free next to a wall is not reachable");
        assert_eq!(img.get_pixel(6, 7), &Rgb([214, 232, 255]), "open floor is tinted reachable");
        let jpg = dir.path().join("room.jpg");
        let err =
            run(MapCommand::Render { path: None, procedural: Some(1), out: jpg.clone() }).expect_err(".jpg");
        assert!(err.to_string().contains("ending in .png"), "{err}");
        assert!(!jpg.exists(), "nothing is written under a name that promises another format");
    }

    #[test]
    fn resample_writes_a_coarser_map_and_refuses_a_finer_one() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut room = tiny_room();
        room.set(1, 13, Cell::Unknown);
        let yaml = dir.path().join("room.yaml");
        save_ros_map(&room, &yaml).expect("save");
        let rule = CoarsenRule::AverageImage;
        let out = dir.path().join("coarse/room.yaml");
        run(MapCommand::Resample { path: yaml.clone(), resolution: 0.2, rule, out: out.clone() })
            .expect("resample");
        let coarse = load_ros_map(&out).expect("the resampled map loads");
        assert_eq!(coarse, room.coarsened(0.2, rule), "written as coarsened, origin and cells");
        let err = run(MapCommand::Resample { path: yaml, resolution: 0.05, rule, out })
            .expect_err("finer than the map");
        assert!(err.to_string().contains("≥ the map's 0.1 m"), "{err}");
    }

    #[test]
    fn export_at_a_coarser_resolution() {
        let dir = tempfile::tempdir().expect("temp dir");
        run(MapCommand::Export { procedural: 4, out: dir.path().into(), resolution: Some(0.1) })
            .expect("export");
        let map = load_ros_map(&dir.path().join("apartment_4.yaml")).expect("loads");
        assert_eq!(map.resolution_m, 0.1);
        assert!(map.counts().2 > 0, "unknown beyond the outer walls is kept");
        let err = run(MapCommand::Export { procedural: 4, out: dir.path().into(), resolution: Some(0.9) })
            .expect_err("out of the generator's range");
        assert!(err.to_string().contains("--resolution"), "{err}");
    }

    #[test]
    fn render_needs_exactly_one_source() {
        let out = PathBuf::from("unused.png");
        let err = run(MapCommand::Render { path: None, procedural: None, out }).expect_err("no source");
        assert!(err.to_string().contains("exactly one"), "{err}");
    }
}
