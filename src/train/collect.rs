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
use safetensors::SafeTensors;
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

/// Reads every shard of a collection back into one episode set (maps regenerated from their
/// names). A damaged or foreign file is an error naming it and the tensor or field at fault.
pub fn load_collection(dir: &Path) -> anyhow::Result<EpisodeSet> {
    let manifest_path = dir.join("manifest.json");
    let manifest: Manifest = serde_json::from_str(
        &std::fs::read_to_string(&manifest_path)
            .with_context(|| format!("reading {}", manifest_path.display()))?,
    )
    .with_context(|| format!("{}: not a collection manifest", manifest_path.display()))?;
    let config: CollectConfig = ron::from_str(&manifest.config)
        .with_context(|| format!("{}: field `config`: not a collect config", manifest_path.display()))?;
    config
        .apartment
        .validate()
        .with_context(|| format!("{}: field `config`: apartment", manifest_path.display()))?;
    let mut all = EpisodeSet::default();
    for file in &manifest.shards {
        let path = dir.join(file);
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let mut shard = read_shard(&bytes).with_context(|| format!("{}: not a shard", path.display()))?;
        for name in &shard.map_names {
            let seed: u64 = name
                .strip_prefix("apartment_")
                .and_then(|n| n.parse().ok())
                .with_context(|| format!("{}: map `{name}`: expected apartment_<seed>", path.display()))?;
            shard.maps.push(NetworkMap::from_fine(&generate_apartment(seed, &config.apartment), 0.1));
        }
        all.extend(shard).with_context(|| format!("{}: unlike the shards before it", path.display()))?;
    }
    Ok(all)
}

/// One shard's episodes, their `map` indexing its own `map_names` (no maps generated), every
/// tensor checked against the layout `encode_shard` writes.
fn read_shard(bytes: &[u8]) -> anyhow::Result<EpisodeSet> {
    let shard = SafeTensors::deserialize(bytes)?;
    let (_, meta) = SafeTensors::read_metadata(bytes)?;
    let metadata = meta.metadata().clone().unwrap_or_default();
    let map_names: Vec<String> = metadata
        .get("maps")
        .map_or("", String::as_str)
        .split(',')
        .filter(|n| !n.is_empty())
        .map(String::from)
        .collect();
    crate::limits::MAPS.check("metadata `maps`", map_names.len()).map_err(anyhow::Error::msg)?;
    let wide_extent_m = match metadata.get("wide_extent_m") {
        Some(text) => Some(
            text.parse::<f32>()
                .ok()
                .filter(|m| m.is_finite() && *m > 0.0)
                .with_context(|| format!("metadata `wide_extent_m`: expected metres > 0, found `{text}`"))?,
        ),
        None => None,
    };
    let grids = shard_tensor(&shard, "grids", Dtype::U8, &[None, None, None, None])?;
    let [e, t, c] = [0, 1, 2].map(|i| grids.shape()[i]);
    anyhow::ensure!(
        grids.shape()[3] == c && t > 0 && c > 0,
        "tensor `grids`: expected [E, T ≥ 1, C ≥ 1, C], found {:?}",
        grids.shape()
    );
    let floats = |name: &str, shape: &[Option<usize>]| -> anyhow::Result<Vec<f32>> {
        let view = shard_tensor(&shard, name, Dtype::F32, shape)?;
        Ok(view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
    };
    let poses = floats("poses", &[Some(e), Some(t), Some(3)])?;
    let odometry = floats("odometry", &[Some(e), Some(t), Some(3)])?;
    let maps = floats("map", &[Some(e)])?;
    // Shards of a schedule without the `depth` step hold no strips, without a wide window one grid.
    let columns = shard.tensor("depths").map_or(0, |view| view.shape().get(2).copied().unwrap_or(0));
    let depths = if columns > 0 { floats("depths", &[Some(e), Some(t), Some(columns)])? } else { vec![] };
    let wide = match wide_extent_m {
        Some(_) => shard_tensor(&shard, "wide_grids", Dtype::U8, &[Some(e), Some(t), Some(c), Some(c)])?
            .data()
            .to_vec(),
        None => vec![],
    };
    let grids = grids.data();
    let pose = |v: &[f32], i: usize| Pose2::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
    let (per_grid, per_strip) = (t * c * c, t * columns);
    let episodes = (0..e)
        .map(|k| {
            let map = maps[k];
            anyhow::ensure!(
                map >= 0.0 && map.fract() == 0.0 && (map as usize) < map_names.len(),
                "tensor `map`: episode {k}'s map {map}, expected an index below the {} names of metadata `maps`",
                map_names.len()
            );
            Ok(RecordedEpisode {
                map: map as usize,
                poses: (0..t).map(|s| pose(&poses, k * t + s)).collect(),
                odometry: (0..t).map(|s| pose(&odometry, k * t + s)).collect(),
                grids: grids[k * per_grid..(k + 1) * per_grid].to_vec(),
                wide_grids: wide.get(k * per_grid..(k + 1) * per_grid).unwrap_or_default().to_vec(),
                depths: depths.get(k * per_strip..(k + 1) * per_strip).unwrap_or_default().to_vec(),
            })
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(EpisodeSet {
        map_names,
        episodes,
        grid_cells: c,
        depth_columns: columns,
        wide_extent_m,
        ..EpisodeSet::default()
    })
}

/// The shard's tensor `name`, checked to hold `dtype` in `shape` (`None`: any length, `_` in errors).
fn shard_tensor<'a>(
    shard: &'a SafeTensors,
    name: &str,
    dtype: Dtype,
    shape: &[Option<usize>],
) -> anyhow::Result<TensorView<'a>> {
    let view = shard.tensor(name).with_context(|| format!("tensor `{name}`"))?;
    let fits = view.shape().len() == shape.len()
        && view.shape().iter().zip(shape).all(|(&n, want)| want.is_none_or(|w| w == n));
    let want: Vec<String> = shape.iter().map(|d| d.map_or("_".into(), |n| n.to_string())).collect();
    anyhow::ensure!(
        view.dtype() == dtype && fits,
        "tensor `{name}`: expected {dtype:?} [{}], found {:?} {:?}",
        want.join(", "),
        view.dtype(),
        view.shape()
    );
    Ok(view)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A shard of one 2-step episode on 2 × 2 grids with `poses` of shape `poses` and `map`'s
    /// one value `map`.
    fn shard(poses: Vec<usize>, map: f32) -> Vec<u8> {
        let floats = |n: usize| vec![0u8; 4 * n];
        let (grids, poses_bytes, odometry) = (vec![0u8; 8], floats(poses.iter().product()), floats(6));
        let map_bytes = map.to_le_bytes();
        let tensors = [
            ("grids", TensorView::new(Dtype::U8, vec![1, 2, 2, 2], &grids).unwrap()),
            ("poses", TensorView::new(Dtype::F32, poses, &poses_bytes).unwrap()),
            ("odometry", TensorView::new(Dtype::F32, vec![1, 2, 3], &odometry).unwrap()),
            ("map", TensorView::new(Dtype::F32, vec![1], &map_bytes).unwrap()),
        ];
        let metadata = HashMap::from([("maps".to_string(), "apartment_1".to_string())]);
        safetensors::serialize(tensors, Some(metadata)).unwrap()
    }

    /// Shapes that disagree and indices beyond the shard's maps are errors naming the tensor,
    /// not an index out of bounds.
    #[test]
    fn a_shard_whose_tensors_disagree_is_refused_by_name() {
        let read = read_shard(&shard(vec![1, 2, 3], 0.0)).unwrap();
        assert_eq!((read.episodes.len(), read.steps(), read.grid_cells), (1, 2, 2));
        let short = read_shard(&shard(vec![1, 1, 3], 0.0)).unwrap_err().to_string();
        assert_eq!(short, "tensor `poses`: expected F32 [1, 2, 3], found F32 [1, 1, 3]");
        let beyond = read_shard(&shard(vec![1, 2, 3], 1.0)).unwrap_err().to_string();
        assert!(
            beyond.starts_with("tensor `map`: episode 0's map 1, expected an index below the 1 names"),
            "{beyond}"
        );
    }
}
