//! SAC checkpoints: the networks as safetensors with their configuration in the metadata (a
//! policy file alone rebuilds its networks), and the learner's whole state (target critics, Adam
//! moments, entropy coefficient) for an exact `--resume`.

use crate::nn::adam::Adam;
use crate::nn::checkpoint::{Checkpoint, CheckpointError};
use crate::nn::sac::config::SacNetConfig;
use crate::nn::sac::networks::SacNetworks;
use crate::nn::sac::update::{SacHyper, SacLearner};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const CONFIG_KEY: &str = "sac_config";
const FORMAT_KEY: &str = "format";
const FORMAT: &str = "apfn-sac-1 (NCHW; conv OIHW, dense [in][out])";
const LEARNER_KEY: &str = "sac_learner";

#[derive(Debug, thiserror::Error)]
pub enum SacFileError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: metadata `{key}`: expected {expected}")]
    Metadata { path: PathBuf, key: &'static str, expected: String },
}

/// The scalar part of a learner's state, kept in the metadata as RON.
#[derive(serde::Serialize, serde::Deserialize)]
struct LearnerScalars {
    hyper: SacHyper,
    adam_step: u64,
    log_alpha: f32,
    alpha_adam: (u64, f32, f32),
}

fn metadata_error(file: &Checkpoint, key: &'static str, expected: String) -> SacFileError {
    SacFileError::Metadata {
        path: file.source.clone().unwrap_or_else(|| "<checkpoint in memory>".into()),
        key,
        expected,
    }
}

impl SacNetworks {
    pub fn to_checkpoint(&self) -> Checkpoint {
        let mut file = Checkpoint::default();
        file.metadata.insert(FORMAT_KEY.into(), FORMAT.into());
        file.metadata.insert(CONFIG_KEY.into(), ron::to_string(&self.config).expect("a config serialises"));
        file.push_buffer(&self.params, &self.params.values, "");
        file
    }

    pub fn from_checkpoint(file: &Checkpoint) -> Result<Self, SacFileError> {
        let text = file
            .metadata
            .get(CONFIG_KEY)
            .ok_or_else(|| metadata_error(file, CONFIG_KEY, "a SacNetConfig (RON)".into()))?;
        let config: SacNetConfig = ron::from_str(text)
            .map_err(|e| metadata_error(file, CONFIG_KEY, format!("a SacNetConfig (RON): {e}")))?;
        config.check().map_err(|e| metadata_error(file, CONFIG_KEY, format!("a valid SacNetConfig: {e}")))?;
        let held = file.value_count();
        if config.weights() > held {
            let expected = format!(
                "a SacNetConfig of at most the {held} weights the file holds; it needs {}",
                config.weights()
            );
            return Err(metadata_error(file, CONFIG_KEY, expected));
        }
        let mut nets = SacNetworks::zeros(&config);
        let mut values = std::mem::take(&mut nets.params.values);
        file.read_buffer(&nets.params, &mut values, "")?;
        nets.params.values = values;
        Ok(nets)
    }

    /// Writes the networks atomically (temporary file + rename).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        self.to_checkpoint().save(path)
    }

    pub fn load(path: &Path) -> Result<Self, SacFileError> {
        Self::from_checkpoint(&Checkpoint::load(path)?)
    }
}

impl SacLearner {
    /// Networks, target critics, Adam moments and α, plus `extra` metadata (the trainer's own state).
    pub fn to_checkpoint(&self, extra: BTreeMap<String, String>) -> Checkpoint {
        let mut file = self.nets.to_checkpoint();
        file.metadata.extend(extra);
        let params = &self.nets.params;
        file.push_buffer(params, &self.target, "target/");
        file.push_buffer(params, &self.adam.m, "adam.m/");
        file.push_buffer(params, &self.adam.v, "adam.v/");
        let scalars = LearnerScalars {
            hyper: self.hyper.clone(),
            adam_step: self.adam.step,
            log_alpha: self.log_alpha,
            alpha_adam: (self.alpha_adam.step, self.alpha_adam.m[0], self.alpha_adam.v[0]),
        };
        file.metadata.insert(LEARNER_KEY.into(), ron::to_string(&scalars).expect("scalars serialise"));
        file
    }

    pub fn from_checkpoint(file: &Checkpoint) -> Result<Self, SacFileError> {
        let nets = SacNetworks::from_checkpoint(file)?;
        let text = file.metadata.get(LEARNER_KEY).ok_or_else(|| {
            metadata_error(file, LEARNER_KEY, "the learner's state (a training checkpoint)".into())
        })?;
        let s: LearnerScalars = ron::from_str(text)
            .map_err(|e| metadata_error(file, LEARNER_KEY, format!("the learner's state: {e}")))?;
        let mut learner = SacLearner::new(nets, s.hyper);
        let params = learner.nets.params.clone();
        file.read_buffer(&params, &mut learner.target, "target/")?;
        file.read_buffer(&params, &mut learner.adam.m, "adam.m/")?;
        file.read_buffer(&params, &mut learner.adam.v, "adam.v/")?;
        learner.adam.step = s.adam_step;
        learner.log_alpha = s.log_alpha;
        let (step, m, v) = s.alpha_adam;
        learner.alpha_adam = Adam { step, m: vec![m], v: vec![v], ..learner.alpha_adam.clone() };
        Ok(learner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::sac::networks::{Observations, PolicyWorkspace};

    #[test]
    fn checkpoint_round_trip_keeps_weights_and_actions() {
        let nets = SacNetworks::new(&SacNetConfig::compact(), 4);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("policy.safetensors");
        nets.save(&path).unwrap();
        let loaded = SacNetworks::load(&path).unwrap();
        assert_eq!(loaded.config, nets.config);
        assert_eq!(loaded.params.values, nets.params.values, "weights survive bit for bit");
        let c = &nets.config;
        let belief = vec![0.5; c.belief_channels * c.belief_cells * c.belief_cells];
        let grid = vec![0.25; c.grid_cells * c.grid_cells];
        let obs = Observations { n: 1, belief: &belief, grid: &grid, state: &[0.1, -0.2, 0.0, 1.0] };
        let act = |n: &SacNetworks| {
            let mut a = [0.0; 2];
            n.act(&obs, None, &mut PolicyWorkspace::default(), &mut a);
            a
        };
        assert_eq!(act(&loaded), act(&nets));

        let learner = SacLearner::new(nets, SacHyper::default());
        let file = learner.to_checkpoint(BTreeMap::new());
        let again = SacLearner::from_checkpoint(&file).unwrap();
        assert_eq!(again.target, learner.target);
        assert_eq!(again.log_alpha, learner.log_alpha);
        let policy_only = SacNetworks::load(&path).unwrap().to_checkpoint();
        let err = SacLearner::from_checkpoint(&policy_only).unwrap_err().to_string();
        assert!(err.contains("sac_learner"), "{err}");
    }

    #[test]
    fn a_policy_asking_for_wider_networks_than_it_holds_is_refused_before_building_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("inflated.safetensors");
        let mut file = SacNetworks::zeros(&SacNetConfig::compact()).to_checkpoint();
        let wide = SacNetConfig { mlp_width: 1 << 40, ..SacNetConfig::compact() };
        file.metadata.insert(CONFIG_KEY.into(), ron::to_string(&wide).unwrap());
        file.save(&path).unwrap();
        let err = SacNetworks::load(&path).unwrap_err().to_string();
        for part in ["inflated.safetensors", CONFIG_KEY, "weights the file holds"] {
            assert!(err.contains(part), "{part:?} missing from: {err}");
        }
    }
}
