//! What `apfn fuzz` feeds: one [`Target`] per kind of file a user hands apfn, each with its valid
//! seed files and the very loader the CLI runs on it. Adding a parser is one entry in [`TARGETS`].

use super::learning_files::{
    collection_corpus, load_collection_of, load_pfnet, load_policy, load_train_pfnet, load_train_sac,
    pfnet_corpus, policy_corpus, train_config_corpus,
};
use super::sample::{Sample, repo_files, tempfile_dir, top_level_struct};
use crate::cli::run::SceneArgs;
use crate::compose::{Pipeline, standard_registry};
use crate::eval::EvalConfig;
use crate::replay::bag::{BagTopics, log_to_bag, read_bag};
use crate::replay::{parse_log, read_log};
use crate::sweep::SweepConfig;
use crate::world::OccupancyMap;
use crate::world::map::{load_ros_map, save_ros_map};
use std::io;
use std::path::Path;

/// One parser under test.
pub struct Target {
    pub name: &'static str,
    /// Valid inputs to mutate, from the repository at the given root or built in code.
    pub corpus: fn(&Path) -> io::Result<Vec<Sample>>,
    /// Loads the entry file as the CLI does, validation included, without simulating anything;
    /// `Err` is a clean error message.
    pub load: fn(&Path) -> Result<(), String>,
}

/// Every parser of user input.
pub const TARGETS: &[Target] = &[
    Target {
        name: "map",
        corpus: map_corpus,
        load: |p| load_ros_map(p).map(drop).map_err(|e| e.to_string()),
    },
    Target {
        name: "scene",
        corpus: |root| ron_corpus(root, "scenes", "Scene", &[ROS_SCENE]),
        load: |p| {
            SceneArgs { scene: Some(p.into()), systems: None }.load().map(drop).map_err(|e| format!("{e:#}"))
        },
    },
    Target {
        name: "schedule",
        corpus: |root| ron_corpus(root, "systems", "Schedule", &[]),
        load: |p| Pipeline::load(p, &standard_registry()).map(drop).map_err(|e| e.to_string()),
    },
    Target {
        name: "eval",
        corpus: |root| ron_corpus(root, "scenes", "Eval", &[ROS_EVAL]),
        load: |p| EvalConfig::load(p).map(drop).map_err(|e| e.to_string()),
    },
    Target {
        name: "sweep",
        corpus: |root| ron_corpus(root, "scenes", "Sweep", &[]),
        load: |p| SweepConfig::load(p).map(drop).map_err(|e| e.to_string()),
    },
    Target {
        name: "replay_log",
        corpus: log_corpus,
        load: |p| read_log(p).map(drop).map_err(|e| e.to_string()),
    },
    Target {
        name: "bag",
        corpus: bag_corpus,
        load: |p| read_bag(p, &BagTopics::default()).map(drop).map_err(|e| e.to_string()),
    },
    Target { name: "pfnet_checkpoint", corpus: pfnet_corpus, load: load_pfnet },
    Target { name: "sac_policy", corpus: policy_corpus, load: load_policy },
    Target {
        name: "train_pfnet",
        corpus: |root| train_config_corpus(root, "train_pfnet_"),
        load: load_train_pfnet,
    },
    Target {
        name: "train_sac",
        corpus: |root| train_config_corpus(root, "train_sac_"),
        load: load_train_sac,
    },
    Target { name: "collection", corpus: collection_corpus, load: load_collection_of },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// Files every input may refer to, written once beside the inputs: the repository's schedules
/// (scenes name `../systems/…`) and a small ROS map (`../maps/room.yaml`).
pub fn context(root: &Path) -> io::Result<Vec<(String, Vec<u8>)>> {
    let mut files = repo_files(root, "systems")?;
    files.extend(room_map("room", "pgm")?);
    Ok(files)
}

/// A scene on the context's ROS map, so that map loading from scenes is mutated too.
const ROS_SCENE: &str = r#"Scene(maps: Ros(paths: ["../maps/room.yaml"]), robots_per_map: 2, seed: 3,
    episode: (steps: 20), robot: (radius_m: 0.18), physics: (dt_s: 0.1, substeps: 6),
    systems: Some("../systems/mcl_passive.ron"))"#;

/// An eval config on the context's ROS map with overrides and an explicit particle count.
const ROS_EVAL: &str = r#"Eval(schedules: ["../systems/mcl_passive.ron"], tasks: [tracking, global],
    maps: [Ros(path: "../maps/room.yaml")], episodes: 4, robots_per_map: 2, particles: Some(300),
    overrides: [("likelihood_field", (max_beams: 30))], localizer: Some("mcl"))"#;

/// The repository's `folder/*.ron` files whose top-level struct is `kind`, plus `extra` texts;
/// each is written as `folder/input.ron` so its relative paths resolve in the scratch folder.
fn ron_corpus(root: &Path, folder: &str, kind: &str, extra: &[&str]) -> io::Result<Vec<Sample>> {
    let entry = format!("{folder}/input.ron");
    let repo = repo_files(root, folder)?
        .into_iter()
        .filter(|(_, text)| top_level_struct(text) == Some(kind))
        .map(|(_, text)| text);
    let samples: Vec<Sample> = repo
        .chain(extra.iter().map(|t| t.as_bytes().to_vec()))
        .map(|text| Sample { files: vec![(entry.clone(), text)] })
        .collect();
    if samples.is_empty() {
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!("no {kind}(…) file in {}", root.join(folder).display()),
        ));
    }
    Ok(samples)
}

/// The tiny test room as a ROS map `maps/<stem>.yaml` with a PGM or PNG image, as bytes.
fn room_map(stem: &str, image: &str) -> io::Result<Vec<(String, Vec<u8>)>> {
    let dir = tempfile_dir()?;
    let yaml = dir.join(format!("{stem}.yaml"));
    save_ros_map(&room(), &yaml).map_err(io::Error::other)?;
    let pgm = dir.join(format!("{stem}.pgm"));
    let mut files = vec![(format!("maps/{stem}.yaml"), std::fs::read(&yaml)?)];
    if image == "png" {
        let img = image::open(&pgm).map_err(io::Error::other)?;
        let mut png = Vec::new();
        img.write_to(&mut io::Cursor::new(&mut png), image::ImageFormat::Png).map_err(io::Error::other)?;
        let text = String::from_utf8_lossy(&files[0].1).replace(".pgm", ".png");
        files[0].1 = text.into_bytes();
        files.push((format!("maps/{stem}.png"), png));
    } else {
        files.push((format!("maps/{stem}.pgm"), std::fs::read(&pgm)?));
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(files)
}

/// Map YAML + image pairs: map_saver's PGM, a PNG, an ASCII PGM, and the other modes and flags.
fn map_corpus(_root: &Path) -> io::Result<Vec<Sample>> {
    let pgm = room_map("input", "pgm")?;
    let png = room_map("input", "png")?;
    let with_yaml = |files: &[(String, Vec<u8>)], from: &str, to: &str| {
        let mut files = files.to_vec();
        files[0].1 = String::from_utf8_lossy(&files[0].1).replace(from, to).into_bytes();
        Sample { files }
    };
    let ascii = vec![
        ("maps/input.yaml".to_owned(), b"image: input.pgm\nresolution: 0.05\norigin: [-1.5, 2.0, 0.3]\nnegate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: scale\n".to_vec()),
        ("maps/input.pgm".to_owned(), b"P2\n# a comment\n4 3\n255\n0 254 254 205\n254 254 254 254\n100 50 254 0\n".to_vec()),
    ];
    Ok(vec![
        Sample { files: pgm.clone() },
        Sample { files: png },
        Sample { files: ascii },
        with_yaml(&pgm, "mode: trinary", "mode: raw"),
        with_yaml(&pgm, "negate: 0", "negate: true"),
    ])
}

/// JSON Lines logs as `apfn record` and Python's `json.dumps` write them.
fn log_corpus(_root: &Path) -> io::Result<Vec<Sample>> {
    let line = |t: f32, x: f32, ranges: &str, truth: &str| {
        format!(
            r#"{{"t": {t}, "odom": [{x}, 0.5, 0.1], "ranges": [{ranges}], "angle_min": -2.094, "angle_increment": 0.0184, "range_min": 0.05, "range_max": 5.6{truth}}}"#
        )
    };
    let recorded = [
        line(0.0, 0.0, "1.2, 1.25, null, 5.6, 0.8, 0.81, 0.83", r#", "truth": [1.0, 1.0, 0.0]"#),
        line(0.6, 0.3, "1.1, 1.2, \"inf\", 5.6, 0.7, 0.71, 0.9", r#", "truth": [1.3, 1.0, 0.05]"#),
        line(1.2, 0.6, "1.0, 1.1, \"nan\", 5.6, 0.6, 0.6, 1.0", ""),
    ]
    .join("\n");
    let python = [
        line(0.0, 0.0, "NaN, 2.0, Infinity, -Infinity, 3.5", r#", "frame_id": "laser", "stamp": {"sec": 1}"#),
        line(0.1, 0.01, "1.5, 2.0, NaN, 4.0, 3.5", ""),
    ]
    .join("\n");
    let entry = |text: String| Sample { files: vec![("logs/input.jsonl".to_owned(), text.into_bytes())] };
    Ok(vec![entry(recorded + "\n"), entry(python + "\n\n")])
}

/// The JSON Lines corpus as a rosbag2 MCAP file with zstd chunks, as `ros2 bag record -s mcap`
/// writes them.
fn bag_corpus(root: &Path) -> io::Result<Vec<Sample>> {
    let mut samples = Vec::new();
    for log in log_corpus(root)? {
        let text = String::from_utf8_lossy(&log.files[0].1).into_owned();
        let lines = parse_log(&text, Path::new("corpus.jsonl")).map_err(io::Error::other)?;
        let bag = log_to_bag(&lines, &BagTopics::default()).map_err(io::Error::other)?;
        samples.push(Sample { files: vec![("logs/input.mcap".to_owned(), bag)] });
    }
    Ok(samples)
}

/// A 2.0 m × 1.5 m room with a pillar, at 0.1 m per cell: the map the corpus refers to.
fn room() -> OccupancyMap {
    let row = |j: usize| -> String {
        (0..20)
            .map(|i| {
                let wall = i == 0 || i == 19 || j == 0 || j == 14;
                let pillar = (11..14).contains(&i) && (4..7).contains(&j);
                if wall || pillar { '#' } else { '.' }
            })
            .collect()
    };
    OccupancyMap::from_ascii(0.1, &(0..15).map(row).collect::<Vec<_>>().join("\n"))
}
