//! PF-net checkpoints: the weights as safetensors (our layouts, the reference's names) with the
//! network's configuration in the metadata, so a file alone rebuilds its network.

use super::config::PfNetConfig;
use super::model::PfNet;
use crate::nn::checkpoint::{Checkpoint, CheckpointError};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Metadata key holding the configuration (RON).
const CONFIG_KEY: &str = "pfnet_config";
/// Metadata key naming the file's kind and layout version.
const FORMAT_KEY: &str = "format";
const FORMAT: &str = "apfn-pfnet-1 (NCHW; conv OIHW, locally-connected [pos][filter][kh·kw·c])";

/// What can go wrong loading a PF-net checkpoint.
#[derive(Debug, thiserror::Error)]
pub enum PfNetFileError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: metadata `{key}`: expected {expected}")]
    Metadata { path: PathBuf, key: &'static str, expected: String },
}

impl PfNet {
    /// The weights and configuration as a checkpoint (plus `extra` metadata, e.g. training state).
    pub fn to_checkpoint(&self, extra: BTreeMap<String, String>) -> Checkpoint {
        let mut file = Checkpoint { metadata: extra, ..Checkpoint::default() };
        file.metadata.insert(FORMAT_KEY.into(), FORMAT.into());
        file.metadata.insert(CONFIG_KEY.into(), ron::to_string(&self.config).expect("a config serialises"));
        file.push_buffer(&self.params, &self.params.values, "");
        file
    }

    /// Writes the checkpoint atomically (temporary file + rename).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        self.to_checkpoint(BTreeMap::new()).save(path)
    }

    /// Rebuilds the network a checkpoint describes and loads its weights.
    pub fn from_checkpoint(file: &Checkpoint) -> Result<Self, PfNetFileError> {
        let path = file.source.clone().unwrap_or_else(|| "<checkpoint in memory>".into());
        let metadata =
            |expected: String| PfNetFileError::Metadata { path: path.clone(), key: CONFIG_KEY, expected };
        let text = file.metadata.get(CONFIG_KEY).ok_or_else(|| metadata("a PfNetConfig (RON)".into()))?;
        let config: PfNetConfig =
            ron::from_str(text).map_err(|e| metadata(format!("a PfNetConfig (RON): {e}")))?;
        config.check().map_err(|e| metadata(format!("a valid PfNetConfig: {e}")))?;
        let held = file.value_count();
        if config.kernel_weights() > held {
            return Err(metadata(format!(
                "a PfNetConfig of at most the {held} weights the file holds; its kernels alone need {}",
                config.kernel_weights()
            )));
        }
        let mut model = PfNet::new(config, 0).map_err(|e| metadata(format!("a valid PfNetConfig: {e}")))?;
        let mut values = std::mem::take(&mut model.params.values);
        file.read_buffer(&model.params, &mut values, "")?;
        model.params.values = values;
        Ok(model)
    }

    /// Loads a checkpoint written by [`PfNet::save`].
    pub fn load(path: &Path) -> Result<Self, PfNetFileError> {
        Self::from_checkpoint(&Checkpoint::load(path)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pfnet::Workspace;

    #[test]
    fn pfnet_checkpoint_round_trip_gives_identical_outputs() {
        let model = PfNet::new(PfNetConfig::compact(), 3).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pfnet.safetensors");
        model.save(&path).unwrap();
        let loaded = PfNet::load(&path).unwrap();
        assert_eq!(loaded.config, model.config);
        assert_eq!(loaded.params.values, model.params.values, "weights survive bit for bit");

        let maps: Vec<f32> = (0..2 * model.local_map_len()).map(|i| (i % 7) as f32 / 6.0).collect();
        let obs: Vec<f32> = (0..model.obs_len()).map(|i| (i % 3) as f32 / 2.0).collect();
        let run = |m: &PfNet| {
            let mut ws = Workspace::default();
            let (mut terms, mut mf) = (vec![0.0; m.obs_term_len()], vec![0.0; 2 * m.map_feature_len()]);
            m.observation_terms(&obs, 1, &mut terms, &mut ws);
            m.encode_local_maps(&maps, 2, &mut mf, &mut ws);
            let mut ll = vec![0.0; 2];
            m.joint_log_likelihoods(&mf, &terms, &[0, 0], &mut ll, &mut ws);
            ll
        };
        assert_eq!(run(&loaded), run(&model), "a loaded network computes the same bytes");
    }

    #[test]
    fn a_checkpoint_asking_for_a_larger_network_than_it_holds_is_refused_before_building_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("inflated.safetensors");
        let mut file = PfNet::new(PfNetConfig::compact(), 0).unwrap().to_checkpoint(BTreeMap::new());
        let huge = PfNetConfig { joint_filters: 1 << 40, ..PfNetConfig::compact() };
        file.metadata.insert(CONFIG_KEY.into(), ron::to_string(&huge).unwrap());
        file.save(&path).unwrap();
        let err = PfNet::load(&path).unwrap_err().to_string();
        for part in ["inflated.safetensors", CONFIG_KEY, "weights the file holds"] {
            assert!(err.contains(part), "{part:?} missing from: {err}");
        }
    }

    #[test]
    fn pfnet_checkpoint_without_config_names_the_file_and_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bare.safetensors");
        let mut bare = PfNet::new(PfNetConfig::compact(), 0).unwrap().to_checkpoint(BTreeMap::new());
        bare.metadata.remove(CONFIG_KEY);
        bare.save(&path).unwrap();
        let err = PfNet::load(&path).unwrap_err().to_string();
        assert!(err.contains("bare.safetensors") && err.contains(CONFIG_KEY), "unhelpful error: {err}");
    }
}
