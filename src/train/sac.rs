//! SAC training: every robot of one world collects with the live policy (one batched forward
//! for all of them, inside `sac_policy`), `sac_update` takes gradient steps between world steps,
//! and this loop only adds what a run needs around the schedule: fresh random streams at each
//! episode boundary, checkpoints and exact resume.
//!
//! Exact resume: all robots start and end their episodes together, so at an episode boundary no
//! action waits for its reward and no robot carries anything into the next episode but its map.
//! There every robot's random streams and the agent's are re-seeded from (seed, robot, episode),
//! and the state saved (networks, optimizers, replay buffer, counters) is all a resumed run needs
//! to continue exactly as the uninterrupted one.

use crate::agent::sac::{SacAgent, SacAgentConfig};
use crate::belief::BeliefParams;
use crate::compose::{LoadedScene, Pipeline, Scene, standard_registry};
use crate::episode::Episode;
use crate::nn::checkpoint::Checkpoint;
use crate::nn::sac::{SacLearner, SacNetConfig, SacNetworks};
use crate::plugin::headless_app;
use crate::world::RobotRngs;
use crate::world::rng::stream;
use anyhow::Context;
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A training run (RON); paths are relative to the config file.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrainSacConfig {
    /// Maps, robots and episode length.
    pub scene: PathBuf,
    /// A schedule with `localization_reward`, `sac_policy` and `sac_update`.
    pub systems: PathBuf,
    /// `paper` or `compact`.
    pub network: String,
    /// Columns of the depth strip the agent reads beside its images (0: none, as the paper); the
    /// schedule must then run the `depth` step with as many `columns`.
    #[serde(default)]
    pub depth_columns: usize,
    /// Belief crops the agent reads: the estimate's, then the next heaviest modes' (1, as the
    /// paper); the schedule's `belief_crop` must then have as many `modes`.
    #[serde(default = "one_crop")]
    pub belief_modes: usize,
    /// Past steps whose crops the agent reads after the present ones (0, as the paper); the
    /// schedule's `belief_crop` must then have as much `history`.
    #[serde(default)]
    pub belief_history: usize,
    /// Whether the agent reads the coarse crop of the whole belief after the modes' (no, as the
    /// paper); the schedule's `belief_crop` must then have an `overview_m`.
    #[serde(default)]
    pub belief_overview: bool,
    #[serde(default)]
    pub agent: SacAgentConfig,
    /// A policy file (`policy.safetensors` of an earlier run) whose encoders, actor and critics
    /// the run starts from instead of fresh ones: fine-tuning, e.g. on another task. The target
    /// critics start as copies of the critics and α at `agent.hyper.initial_alpha`; the network
    /// must be the one `network`, `depth_columns` and `belief_modes` describe, or have fewer
    /// belief channels (a policy trained without `belief_history` or `belief_overview`, whose new
    /// channels then start at zero weight). Relative to the config file.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// World steps to train for (each moves every robot once).
    pub steps: u64,
    /// World steps between resumable checkpoints; a multiple of the episode length.
    pub checkpoint_every: u64,
    /// World steps between kept copies of the policy, `policy_<step>.safetensors` (none by
    /// default): the last policy of a run is not always its best, and choosing one takes
    /// hundreds of held-out episodes per checkpoint (`docs/results/sac_global_cap/`).
    #[serde(default)]
    pub snapshot_every: Option<u64>,
    /// World steps between rows of the training log.
    pub log_every: u64,
    pub seed: u64,
}

impl TrainSacConfig {
    pub fn net_config(&self) -> Result<SacNetConfig, String> {
        let named = match self.network.as_str() {
            "paper" => SacNetConfig::paper(),
            "compact" => SacNetConfig::compact(),
            other => return Err(format!("network: expected `paper` or `compact`, found `{other}`")),
        };
        crate::limits::BELIEF_MODES.check("belief_modes", self.belief_modes)?;
        crate::limits::BELIEF_HISTORY.check("belief_history", self.belief_history)?;
        // The overview's cell side is the schedule's; only whether there is one counts here.
        let crops = BeliefParams {
            modes: self.belief_modes,
            history: self.belief_history,
            overview_m: self.belief_overview.then_some(0.4),
            ..Default::default()
        };
        let config =
            SacNetConfig { depth_columns: self.depth_columns, belief_channels: crops.channels(), ..named };
        config.check()?;
        Ok(config)
    }

    pub fn check(&self) -> Result<(), String> {
        self.net_config()?;
        self.agent.check().map_err(|e| format!("agent.{e}"))?;
        let positive = |v: u64, field: &str| {
            if v > 0 { Ok(()) } else { Err(format!("{field}: expected ≥ 1 world step")) }
        };
        positive(self.steps, "steps")?;
        positive(self.checkpoint_every, "checkpoint_every")?;
        if let Some(every) = self.snapshot_every {
            positive(every, "snapshot_every")?;
        }
        positive(self.log_every, "log_every")
    }
}

fn one_crop() -> usize {
    1
}

/// Names of the files of a run's resumable state.
pub const STATE_FILE: &str = "state.safetensors";

/// The replay buffer saved with the state of step `step` (named by step, so that the state file
/// never points at a buffer written for another step, even if a run dies between the two writes).
pub fn replay_file(step: u64) -> String {
    format!("replay_{step}.safetensors")
}
const STEP_KEY: &str = "train_step";
const CONFIG_KEY: &str = "train_config";
const COUNTS_KEY: &str = "agent_counts";

/// A world with the learning agent in it.
pub struct SacTrainer {
    pub config: TrainSacConfig,
    pub app: App,
    robots: Vec<Entity>,
    agent: Entity,
    episode_steps: u64,
    /// World steps done.
    pub step: u64,
}

impl SacTrainer {
    /// A fresh run of the config at `path`.
    pub fn new(config: TrainSacConfig, path: &Path) -> anyhow::Result<Self> {
        config.check().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let loaded: LoadedScene = Scene::load(&dir.join(&config.scene))?;
        let pipeline = Pipeline::load(&dir.join(&config.systems), &standard_registry())?;
        for needed in ["localization_reward", "sac_policy", "sac_update"] {
            anyhow::ensure!(
                pipeline.names().contains(&needed),
                "{}: the schedule {} has no `{needed}` step",
                path.display(),
                config.systems.display()
            );
        }
        let episode_steps = u64::from(loaded.scene.episode.steps);
        // State is saved at episode boundaries only, and the last step always saves it.
        for (field, value) in [("checkpoint_every", config.checkpoint_every), ("steps", config.steps)] {
            anyhow::ensure!(
                value.is_multiple_of(episode_steps),
                "{}: {field}: expected a multiple of the episode length ({episode_steps} steps), got {value}",
                path.display(),
            );
        }
        let (mut app, robots) = headless_app(&loaded, pipeline)?;
        let net = config.net_config().map_err(anyhow::Error::msg)?;
        // The schedule's crops must be the network's input; a mismatch would only warn per step.
        let crops = app.world().get_resource::<BeliefParams>().cloned().unwrap_or_default();
        for (field, step_field, scheduled, configured) in [
            ("belief_modes", "modes", crops.modes.to_string(), config.belief_modes.to_string()),
            ("belief_history", "history", crops.history.to_string(), config.belief_history.to_string()),
            (
                "belief_overview",
                "overview_m",
                crops.overview_m.is_some().to_string(),
                config.belief_overview.to_string(),
            ),
        ] {
            anyhow::ensure!(
                scheduled == configured,
                "{}: {field}: expected {scheduled}, the `{step_field}` of belief_crop in {}, got {configured}",
                path.display(),
                config.systems.display(),
            );
        }
        let nets = match &config.init {
            None => SacNetworks::new(&net, config.seed),
            Some(init) => {
                let init = dir.join(init);
                let nets = SacNetworks::load(&init).with_context(|| format!("{}: init", path.display()))?;
                nets.widened(&net)
                    .map_err(|e| anyhow::anyhow!("{}: init: {}: {e}", path.display(), init.display()))?
            }
        };
        let learner = SacLearner::new(nets, config.agent.hyper.clone());
        let agent = SacAgent::with_learner(
            learner,
            config.agent.clone(),
            robots.len(),
            episode_steps as usize,
            config.seed,
        );
        let agent = app.world_mut().spawn(agent).id();
        Ok(Self { config, app, robots, agent, episode_steps, step: 0 })
    }

    /// The run saved in `dir`, ready to continue; `steps` and `snapshot_every` may differ from
    /// the saved config (to extend a finished run), nothing that changes training may.
    pub fn resume(config: TrainSacConfig, path: &Path, dir: &Path) -> anyhow::Result<Self> {
        let mut trainer = Self::new(config, path)?;
        let state = dir.join(STATE_FILE);
        let file = Checkpoint::load(&state)?;
        let saved = file.metadata.get(CONFIG_KEY).map(String::as_str).unwrap_or_default();
        let same_training = ron::from_str::<TrainSacConfig>(saved).is_ok_and(|saved| {
            let current = &trainer.config;
            TrainSacConfig { steps: current.steps, snapshot_every: current.snapshot_every, ..saved }
                == *current
        });
        anyhow::ensure!(
            same_training,
            "--resume: {} was trained with another config than {} (only `steps` and `snapshot_every` may change)",
            state.display(),
            path.display()
        );
        let numbers = |key: &str, len: usize| -> anyhow::Result<Vec<u64>> {
            let text = file
                .metadata
                .get(key)
                .with_context(|| format!("{}: metadata `{key}` missing", state.display()))?;
            let numbers: Vec<u64> =
                ron::from_str(text).with_context(|| format!("{}: metadata `{key}`", state.display()))?;
            anyhow::ensure!(
                numbers.len() == len,
                "{}: metadata `{key}`: expected {len} numbers, found `{text}`",
                state.display()
            );
            Ok(numbers)
        };
        let step = numbers(STEP_KEY, 1)?[0];
        anyhow::ensure!(
            step.is_multiple_of(trainer.episode_steps),
            "{}: metadata `{STEP_KEY}`: step {step}, expected an episode boundary (a multiple of {})",
            state.display(),
            trainer.episode_steps
        );
        let counts = numbers(COUNTS_KEY, 3)?;
        let learner = SacLearner::from_checkpoint(&file)?;
        let mut agent = trainer.agent_mut();
        agent.replay = crate::agent::sac::ReplayBuffer::load(&dir.join(replay_file(step)), &agent.replay)?;
        agent.learner = learner;
        (agent.transitions, agent.updates, agent.steps) = (counts[0], counts[1], counts[2]);
        trainer.step = step;
        if step > 0 {
            // Every robot is in the last step of the episode before the boundary, as it was.
            let episode = (step / trainer.episode_steps) as u32;
            for &robot in &trainer.robots {
                let steps = trainer.episode_steps as u32;
                trainer.app.world_mut().entity_mut(robot).insert(Episode { index: episode - 1, step: steps });
            }
        }
        Ok(trainer)
    }

    /// Agent steps per episode.
    pub fn episode_steps(&self) -> u64 {
        self.episode_steps
    }

    pub fn agent(&self) -> &SacAgent {
        self.app.world().get::<SacAgent>(self.agent).expect("the agent entity lives as long as the trainer")
    }

    pub fn agent_mut(&mut self) -> Mut<'_, SacAgent> {
        self.app
            .world_mut()
            .get_mut::<SacAgent>(self.agent)
            .expect("the agent entity lives as long as the trainer")
    }

    /// One world step; at an episode boundary, fresh random streams first.
    pub fn step(&mut self) {
        if self.step.is_multiple_of(self.episode_steps) {
            let (seed, episode) = (self.config.seed, self.step / self.episode_steps);
            for (index, &robot) in self.robots.iter().enumerate() {
                let key = stream(&[seed, index as u64, episode]).random::<u64>();
                self.app.world_mut().entity_mut(robot).insert(RobotRngs::seeded(key));
            }
            self.agent_mut().rng = stream(&[seed, 0x5ac, episode]);
        }
        self.app.update();
        self.step += 1;
    }

    /// Whether a resumable checkpoint is due after this step.
    pub fn checkpoint_due(&self) -> bool {
        self.step.is_multiple_of(self.config.checkpoint_every) || self.step == self.config.steps
    }

    /// The file name of the policy kept after this step, if `snapshot_every` asks for one.
    pub fn snapshot_due(&self) -> Option<String> {
        let every = self.config.snapshot_every?;
        self.step.is_multiple_of(every).then(|| format!("policy_{}.safetensors", self.step))
    }

    /// Writes the resumable state (learner, replay buffer, counters) into `dir`, atomically per file.
    pub fn save_state(&self, dir: &Path) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.step.is_multiple_of(self.episode_steps),
            "state is saved at episode boundaries only"
        );
        let agent = self.agent();
        let mut extra = BTreeMap::new();
        extra.insert(STEP_KEY.into(), format!("[{}]", self.step));
        extra.insert(
            COUNTS_KEY.into(),
            format!("[{}, {}, {}]", agent.transitions, agent.updates, agent.steps),
        );
        extra.insert(CONFIG_KEY.into(), ron::to_string(&self.config)?);
        // The buffer first, then the state naming it, then the buffers no state names any more.
        agent.replay.save(&dir.join(replay_file(self.step)))?;
        agent.learner.to_checkpoint(extra).save(&dir.join(STATE_FILE))?;
        for entry in std::fs::read_dir(dir)?.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with("replay_") && name.ends_with(".safetensors") && name != replay_file(self.step)
            {
                std::fs::remove_file(entry.path())?;
            }
        }
        Ok(())
    }
}
