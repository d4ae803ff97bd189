//! The learned half's files for `apfn fuzz`: PF-net checkpoints, SAC policies, the two training
//! configs and `apfn collect`'s episode collections. Checkpoints carry their network's shape as RON in the safetensors header, so
//! a damaged or hand-edited file can ask for any size of network: the corpus holds the shipped
//! compact shape (mostly weights, so flips land in the data) and a tiny one (mostly header, so
//! edits land in the shape and the tensor table).

use super::sample::{Sample, repo_files, tempfile_dir, top_level_struct};
use crate::compose::read_ron;
use crate::nn::checkpoint::{Checkpoint, Storage};
use crate::nn::pfnet::{ConvBranch, LocalMapSpec, PfNet, PfNetConfig};
use crate::nn::sac::{SacNetConfig, SacNetworks};
use crate::train::collect::{CollectConfig, collect, load_collection};
use crate::train::pfnet::TrainPfNetConfig;
use crate::train::sac::TrainSacConfig;
use std::collections::BTreeMap;
use std::io;
use std::path::Path;

/// Loads a PF-net checkpoint as `pfnet_likelihood (checkpoint: …)` does.
pub fn load_pfnet(path: &Path) -> Result<(), String> {
    PfNet::load(path).map(drop).map_err(|e| e.to_string())
}

/// Loads a policy as `sac_policy (checkpoint: …)` does.
pub fn load_policy(path: &Path) -> Result<(), String> {
    SacNetworks::load(path).map(drop).map_err(|e| e.to_string())
}

/// Reads and checks a `train-pfnet` config: what the CLI does before simulating any data.
pub fn load_train_pfnet(path: &Path) -> Result<(), String> {
    let config: TrainPfNetConfig = read_ron(path).map_err(|e| e.to_string())?;
    config.check().map_err(|e| format!("{}: {e}", path.display()))
}

/// Reads a collection as `train-pfnet` does for `data: Some(folder)`; the entry file is its shard.
pub fn load_collection_of(shard: &Path) -> Result<(), String> {
    load_collection(shard.parent().unwrap_or(Path::new("."))).map(drop).map_err(|e| format!("{e:#}"))
}

/// Reads and checks a `train-sac` config: what the CLI does before building the world.
pub fn load_train_sac(path: &Path) -> Result<(), String> {
    let config: TrainSacConfig = read_ron(path).map_err(|e| e.to_string())?;
    config.check().map_err(|e| format!("{}: {e}", path.display()))
}

/// The compact PF-net in F32 and F16, and a tiny one.
pub fn pfnet_corpus(_root: &Path) -> io::Result<Vec<Sample>> {
    let compact = PfNet::new(PfNetConfig::compact(), 0).map_err(io::Error::other)?;
    let tiny = PfNet::new(tiny_pfnet(), 0).map_err(io::Error::other)?;
    let (compact, tiny) = (compact.to_checkpoint(BTreeMap::new()), tiny.to_checkpoint(BTreeMap::new()));
    let half = Checkpoint { storage: Storage::F16, ..compact.clone() };
    [compact, half, tiny].iter().map(checkpoint_sample).collect()
}

/// The compact policy and a tiny one.
pub fn policy_corpus(_root: &Path) -> io::Result<Vec<Sample>> {
    let tiny = SacNetConfig {
        conv_channels: vec![2],
        encoder_fc: 3,
        mlp_width: 4,
        belief_cells: 3,
        grid_cells: 3,
        ..SacNetConfig::compact()
    };
    [SacNetConfig::compact(), tiny]
        .iter()
        .map(|config| checkpoint_sample(&SacNetworks::zeros(config).to_checkpoint()))
        .collect()
}

/// PF-net's structure at its smallest: one filter per branch, 8 × 8 local maps.
fn tiny_pfnet() -> PfNetConfig {
    let one = |kernel, dilation| vec![ConvBranch { filters: 1, kernel, dilation }];
    PfNetConfig {
        local_map: LocalMapSpec { cells: 8, ..LocalMapSpec::default() },
        obs_cells: 16,
        map_stage1: [one(3, 1), one(5, 2)].concat(),
        map_stage2: one(3, 1),
        obs_stage1: one(3, 1),
        obs_stage2: one(3, 1),
        joint_filters: 1,
        ..PfNetConfig::compact()
    }
}

/// A collection of two 3-step episodes on one apartment, written by `apfn collect`'s code with
/// the repository's schedule: the shard first (the file mutated most), then the manifest.
pub fn collection_corpus(root: &Path) -> io::Result<Vec<Sample>> {
    let dir = tempfile_dir()?;
    let config = CollectConfig {
        shards: 1,
        maps_per_shard: 1,
        episodes_per_shard: 2,
        steps: 3,
        schedule: root.join("systems/collect_pfnet.ron").to_string_lossy().into_owned(),
        ..CollectConfig::default()
    };
    collect(&config, &dir, |_, _| {}).map_err(|e| io::Error::other(format!("{e:#}")))?;
    let files = ["shard_00000.safetensors", "manifest.json"]
        .into_iter()
        .map(|name| Ok((format!("data/{name}"), std::fs::read(dir.join(name))?)))
        .collect::<io::Result<Vec<_>>>()?;
    std::fs::remove_dir_all(&dir)?;
    Ok(vec![Sample { files }])
}

/// A checkpoint's bytes as `models/input.safetensors`.
fn checkpoint_sample(file: &Checkpoint) -> io::Result<Sample> {
    let dir = tempfile_dir()?;
    let path = dir.join("input.safetensors");
    file.save(&path).map_err(io::Error::other)?;
    let bytes = std::fs::read(&path)?;
    std::fs::remove_dir_all(&dir)?;
    Ok(Sample { files: vec![("models/input.safetensors".to_owned(), bytes)] })
}

/// The repository's training configs `scenes/<prefix>*.ron` (unnamed structs, unlike the scenes
/// beside them), each written as `scenes/input.ron` so that its relative paths resolve as they do
/// in the repository.
pub fn train_config_corpus(root: &Path, prefix: &str) -> io::Result<Vec<Sample>> {
    let samples: Vec<Sample> = repo_files(root, "scenes")?
        .into_iter()
        .filter(|(name, text)| {
            name.starts_with(&format!("scenes/{prefix}")) && top_level_struct(text).is_none()
        })
        .map(|(_, text)| Sample { files: vec![("scenes/input.ron".to_owned(), text)] })
        .collect();
    if samples.is_empty() {
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!("no scenes/{prefix}*.ron under {}", root.display()),
        ));
    }
    Ok(samples)
}
