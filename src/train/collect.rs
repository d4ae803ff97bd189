//! `apfn collect`: PF-net's training episodes written to disk, for training without simulating
//! or for other tools. Shards of episodes (safetensors, readable from Python: `grids` u8
//! [E, T, cells, cells], `poses` and `odometry` f32 [E, T, 3] as (x, y, θ), `map` f32 [E] — an
//! index into the shard's `maps` metadata, comma-separated apartment names, and `depths` f32
//! [E, T, columns] in metres when the schedule runs the `depth` step, `wide_grids` u8 as `grids`
//! with the window in the `wide_extent_m` metadata when its `local_grid` has one) and
//! `manifest.json`.
//! Each shard simulates its own apartments from its own seed, so shards are independent:
//! a collection stopped midway resumes at the first missing shard.

use crate::compose::{MapSource, Pipeline, Scene, standard_registry};
use crate::train::episodes::{EpisodeSet, RecordedEpisode, simulate_episodes};
use crate::world::Pose2;
use crate::world::map::procedural::{ApartmentParams, Split, generate_apartment};
use crate::world::map::{NetworkMap, write_atomically};
use anyhow::{Context, bail};
use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// What to collect.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CollectConfig {
    /// Apartments to drive on (default: the paper's size range with scan realism) and their split.
    pub apartment: ApartmentParams,
    pub split: Split,
    /// Shards, apartments per shard and episodes per shard (paper: 4,000 episodes in all).
    pub shards: usize,
    pub maps_per_shard: usize,
    pub episodes_per_shard: usize,
    /// Agent steps per episode (paper: 25).
    pub steps: u32,
    /// Root of every random stream; shard k uses seed + k.
    pub seed: u64,
    /// The schedule that drives (relative to the working directory).
    pub schedule: String,
}

impl Default for CollectConfig {
    fn default() -> Self {
        Self {
            apartment: ApartmentParams::paper_size(),
            split: Split::Seen,
            shards: 8,
            maps_per_shard: 25,
            episodes_per_shard: 500,
            steps: 25,
            seed: 0,
            schedule: "systems/collect_pfnet.ron".into(),
        }
    }
}

/// `manifest.json`: the config and the shards written so far.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Default)]
pub struct Manifest {
    pub config: String,
    pub shards: Vec<String>,
}

/// Collects every shard not yet in `out`'s manifest; `progress(shard, episodes done)`.
pub fn collect(
    config: &CollectConfig,
    out: &Path,
    progress: impl Fn(usize, usize),
) -> anyhow::Result<Manifest> {
    for (field, value) in [("shards", config.shards), ("maps_per_shard", config.maps_per_shard)] {
        anyhow::ensure!((1..=100_000).contains(&value), "{field}: expected 1 to 100,000, found {value}");
    }
    anyhow::ensure!(
        (1..=1_000_000).contains(&config.episodes_per_shard),
        "episodes_per_shard: expected 1 to 1,000,000"
    );
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let manifest_path = out.join("manifest.json");
    let config_ron = ron::to_string(config)?;
    let mut manifest = match std::fs::read_to_string(&manifest_path) {
        Ok(text) => serde_json::from_str::<Manifest>(&text)
            .with_context(|| format!("{}: not a collection manifest", manifest_path.display()))?,
        Err(_) => Manifest { config: config_ron.clone(), shards: vec![] },
    };
    if manifest.config != config_ron {
        bail!("{} was collected with another config; use a new --out", out.display());
    }
    let pipeline = Pipeline::load(Path::new(&config.schedule), &standard_registry())?;
    for shard in manifest.shards.len()..config.shards {
        let mut scene =
            Scene::apartments(config.split, (shard * config.maps_per_shard) as u64, config.maps_per_shard, 4);
        if let MapSource::Procedural { params, .. } = &mut scene.maps {
            *params = config.apartment.clone();
        }
        scene.seed = config.seed.wrapping_add(shard as u64);
        scene.episode.steps = config.steps;
        let loaded = scene.into_loaded(Path::new("collect"))?;
        let set = simulate_episodes(&loaded, pipeline.clone(), config.episodes_per_shard, |done| {
            progress(shard, done)
        })?;
        let file = format!("shard_{shard:05}.safetensors");
        write_atomically(&out.join(&file), &encode_shard(&set)?)?;
        manifest.shards.push(file);
        write_atomically(&manifest_path, serde_json::to_string_pretty(&manifest)?.as_bytes())?;
    }
    Ok(manifest)
}

fn encode_shard(set: &EpisodeSet) -> anyhow::Result<Vec<u8>> {
    let (e, t, c) = (set.episodes.len(), set.steps(), set.grid_cells);
    let grids: Vec<u8> = set.episodes.iter().flat_map(|ep| ep.grids.iter().copied()).collect();
    let wide_grids: Vec<u8> = set.episodes.iter().flat_map(|ep| ep.wide_grids.iter().copied()).collect();
    let pose_bytes = |pick: fn(&RecordedEpisode) -> &Vec<Pose2>| -> Vec<u8> {
        set.episodes
            .iter()
            .flat_map(|ep| pick(ep).iter().flat_map(|p| [p.x, p.y, p.yaw]))
            .flat_map(f32::to_le_bytes)
            .collect()
    };
    let (poses, odometry) = (pose_bytes(|ep| &ep.poses), pose_bytes(|ep| &ep.odometry));
    let maps: Vec<u8> = set.episodes.iter().flat_map(|ep| (ep.map as f32).to_le_bytes()).collect();
    let depths: Vec<u8> =
        set.episodes.iter().flat_map(|ep| ep.depths.iter().flat_map(|d| d.to_le_bytes())).collect();
    let mut tensors = vec![
        ("grids", TensorView::new(Dtype::U8, vec![e, t, c, c], &grids)?),
        ("poses", TensorView::new(Dtype::F32, vec![e, t, 3], &poses)?),
        ("odometry", TensorView::new(Dtype::F32, vec![e, t, 3], &odometry)?),
        ("map", TensorView::new(Dtype::F32, vec![e], &maps)?),
    ];
    if set.depth_columns > 0 {
        tensors.push(("depths", TensorView::new(Dtype::F32, vec![e, t, set.depth_columns], &depths)?));
    }
    let mut metadata = HashMap::from([("maps".to_string(), set.map_names.join(","))]);
    if let Some(extent_m) = set.wide_extent_m {
        tensors.push(("wide_grids", TensorView::new(Dtype::U8, vec![e, t, c, c], &wide_grids)?));
        metadata.insert("wide_extent_m".to_string(), extent_m.to_string());
    }
    Ok(safetensors::serialize(tensors, Some(metadata))?)
}

/// Reads every shard of a collection back into one episode set (maps regenerated from their names).
pub fn load_collection(dir: &Path) -> anyhow::Result<EpisodeSet> {
    let manifest_path = dir.join("manifest.json");
    let manifest: Manifest = serde_json::from_str(
        &std::fs::read_to_string(&manifest_path)
            .with_context(|| format!("reading {}", manifest_path.display()))?,
    )
    .with_context(|| format!("{}: not a collection manifest", manifest_path.display()))?;
    let config: CollectConfig = ron::from_str(&manifest.config)?;
    let mut all = EpisodeSet::default();
    for file in &manifest.shards {
        let path = dir.join(file);
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let shard = safetensors::SafeTensors::deserialize(&bytes)
            .with_context(|| format!("{}: not a shard", path.display()))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)?;
        let names = meta.metadata().as_ref().and_then(|m| m.get("maps")).cloned().unwrap_or_default();
        let wide_extent_m = match meta.metadata().as_ref().and_then(|m| m.get("wide_extent_m")) {
            Some(text) => Some(
                text.parse::<f32>()
                    .with_context(|| format!("{}: metadata `wide_extent_m`: `{text}`", path.display()))?,
            ),
            None => None,
        };
        // Shards of a schedule without a wide window hold one grid.
        let wide_grids = match wide_extent_m {
            Some(_) => shard
                .tensor("wide_grids")
                .with_context(|| format!("{}: tensor `wide_grids`", path.display()))?
                .data()
                .to_vec(),
            None => vec![],
        };
        let first_map = all.maps.len();
        for name in names.split(',').filter(|n| !n.is_empty()) {
            let seed: u64 = name
                .trim_start_matches("apartment_")
                .parse()
                .with_context(|| format!("{}: map `{name}`", path.display()))?;
            all.maps.push(NetworkMap::from_fine(&generate_apartment(seed, &config.apartment), 0.1));
            all.map_names.push(name.to_string());
        }
        let floats = |name: &str| -> anyhow::Result<Vec<f32>> {
            let view = shard.tensor(name).with_context(|| format!("{}: tensor `{name}`", path.display()))?;
            Ok(view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
        };
        let grids = shard.tensor("grids").with_context(|| format!("{}: tensor `grids`", path.display()))?;
        let (e, t, c) = (grids.shape()[0], grids.shape()[1], grids.shape()[2]);
        let (poses, odometry, maps) = (floats("poses")?, floats("odometry")?, floats("map")?);
        // Shards of a schedule without the `depth` step hold no strips.
        let columns = shard.tensor("depths").map_or(0, |view| view.shape()[2]);
        let depths = if columns > 0 { floats("depths")? } else { vec![] };
        let pose = |v: &[f32], i: usize| Pose2::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
        for (k, &map) in maps.iter().enumerate().take(e) {
            all.episodes.push(RecordedEpisode {
                map: first_map + map as usize,
                poses: (0..t).map(|s| pose(&poses, k * t + s)).collect(),
                odometry: (0..t).map(|s| pose(&odometry, k * t + s)).collect(),
                grids: grids.data()[k * t * c * c..(k + 1) * t * c * c].to_vec(),
                wide_grids: wide_grids.get(k * t * c * c..(k + 1) * t * c * c).unwrap_or_default().to_vec(),
                depths: depths.get(k * t * columns..(k + 1) * t * columns).unwrap_or_default().to_vec(),
            });
        }
        all.grid_cells = c;
        all.depth_columns = columns;
        all.wide_extent_m = wide_extent_m;
    }
    Ok(all)
}
