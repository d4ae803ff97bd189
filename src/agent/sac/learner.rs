//! The learning agent: one entity holding SAC's networks and optimizers, the replay buffer, its
//! own random stream and what each robot's last action still waits for.

use crate::agent::sac::observation::ObservationShape;
use crate::agent::sac::replay::{ReplayBuffer, SampledBatch};
use crate::nn::sac::{ACTION_LEN, SacHyper, SacLearner, SacNetConfig, SacNetworks, UpdateStats};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// How the agent learns; defaults are the paper's (the authors' SB3 run).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SacAgentConfig {
    pub hyper: SacHyper,
    /// Transitions the replay buffer keeps.
    pub buffer: usize,
    /// Transitions per gradient step.
    pub batch: usize,
    /// Transitions collected with uniformly random actions before the first update.
    pub learning_starts: usize,
}

impl Default for SacAgentConfig {
    fn default() -> Self {
        Self { hyper: SacHyper::default(), buffer: 50_000, batch: 256, learning_starts: 1_000 }
    }
}

impl SacAgentConfig {
    pub fn check(&self) -> Result<(), String> {
        self.hyper.check().map_err(|e| format!("hyper.{e}"))?;
        if self.buffer == 0 || self.buffer > 10_000_000 {
            return Err(format!("buffer: expected 1 to 10,000,000 transitions, got {}", self.buffer));
        }
        if self.batch == 0 || self.batch > self.buffer {
            return Err(format!(
                "batch: expected 1 to `buffer` ({}) transitions, got {}",
                self.buffer, self.batch
            ));
        }
        Ok(())
    }
}

/// A robot's last action, waiting for the reward and the observation that follow it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pending {
    pub obs: u64,
    pub action: [f32; ACTION_LEN],
}

/// What one finished episode earned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeReturn {
    pub total: f32,
    /// −r of the last step: the squared pose error the episode ended with (m² + 0.36 rad²),
    /// plus the collision penalty if the last action bumped.
    pub final_loss: f32,
}

#[derive(Component, Clone, Debug)]
pub struct SacAgent {
    pub config: SacAgentConfig,
    pub learner: SacLearner,
    pub replay: ReplayBuffer,
    pub rng: Pcg64Mcg,
    pub pending: BTreeMap<Entity, Pending>,
    /// Running return of each robot's episode.
    pub returns: BTreeMap<Entity, f32>,
    /// Episodes finished since the trainer last drained them.
    pub finished: Vec<EpisodeReturn>,
    /// Update statistics since the trainer last drained them.
    pub stats: Vec<UpdateStats>,
    pub transitions: u64,
    pub updates: u64,
    /// World steps `sac_update` has seen (its cadence counts them).
    pub steps: u64,
    batch: SampledBatch,
    indices: Vec<usize>,
    noise: Vec<f32>,
}

impl SacAgent {
    /// A fresh agent with networks drawn from `seed`, for `robots` robots in episodes of
    /// `episode_steps` steps.
    pub fn new(
        net: &SacNetConfig,
        config: SacAgentConfig,
        robots: usize,
        episode_steps: usize,
        seed: u64,
    ) -> Self {
        let learner = SacLearner::new(SacNetworks::new(net, seed), config.hyper.clone());
        Self::with_learner(learner, config, robots, episode_steps, seed)
    }

    pub fn with_learner(
        learner: SacLearner,
        config: SacAgentConfig,
        robots: usize,
        episode_steps: usize,
        seed: u64,
    ) -> Self {
        let shape = ObservationShape::of(&learner.nets.config);
        Self {
            replay: ReplayBuffer::new(config.buffer, episode_steps, robots, shape),
            rng: crate::world::rng::stream(&[seed, 0x5ac]),
            config,
            learner,
            pending: BTreeMap::new(),
            returns: BTreeMap::new(),
            finished: Vec::new(),
            stats: Vec::new(),
            transitions: 0,
            updates: 0,
            steps: 0,
            batch: SampledBatch::default(),
            indices: Vec::new(),
            noise: Vec::new(),
        }
    }

    /// Still collecting with random actions.
    pub fn warming_up(&self) -> bool {
        self.replay.len() < self.config.learning_starts.max(self.config.batch)
    }

    /// One gradient step on a uniformly drawn minibatch.
    pub fn train_once(&mut self) -> UpdateStats {
        let (n, len) = (self.config.batch, self.replay.len());
        self.indices.clear();
        self.indices.extend((0..n).map(|_| self.rng.random_range(0..len)));
        self.noise.clear();
        self.noise.extend((0..2 * n * ACTION_LEN).map(|_| self.rng.sample::<f32, _>(StandardNormal)));
        self.replay.sample(&self.indices, &mut self.batch);
        let stats = self.learner.update(&self.batch.transitions(), &self.noise);
        self.updates += 1;
        self.stats.push(stats);
        stats
    }
}
