//! `sac_policy`: one batched actor forward pass for every robot in the world. With a learning
//! agent in the world it samples actions (uniformly at random while warming up) and stores each
//! robot's transitions; otherwise it acts with a policy checkpoint, deterministically, tanh(μ),
//! or, with `sample`, by drawing from the policy as training does, or, with `candidates`, by the
//! checkpoint's critics' choice among tanh(μ) and actions drawn from the policy.

use crate::act::Collided;
use crate::agent::Action;
use crate::agent::sac::learner::{EpisodeReturn, Pending, SacAgent};
use crate::agent::sac::observation::{
    ObservationShape, decode, encode_belief, encode_depth, encode_grid, robot_state,
};
use crate::agent::sac::reward::Reward;
use crate::belief::{BELIEF_CHANNELS, BeliefCrop, BeliefParams};
use crate::episode::{Episode, EpisodeEnd, EpisodeParams};
use crate::nn::sac::{ACTION_LEN, Candidates, Observations, PolicyWorkspace, STATE_LEN, SacNetworks};
use crate::params::StepParams;
use crate::sense::{DepthParams, DepthStrip, LocalGrid, LocalGridParams};
use crate::world::{RobotId, ScenarioRng, in_id_order};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock};

#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SacPolicyParams {
    /// A policy written by `apfn train-sac` (safetensors), relative to the working directory.
    /// Unused while a learning agent is in the world (training acts with its live networks).
    pub checkpoint: Option<String>,
    /// Draw each action from the tanh-Gaussian policy with the robot's scenario RNG instead of
    /// taking tanh(μ) (default false, the deterministic actions SAC is evaluated with). A policy
    /// that sees only its present observation can loop where its observations repeat, and
    /// drawn actions can break such loops (Singh, Jaakkola & Jordan 1994); for the shipped
    /// global agent they did not help (docs/results/sac_sampled/).
    pub sample: bool,
    /// Actions weighed per step (default 1, tanh(μ) alone): with k > 1, tanh(μ) and k − 1 actions
    /// drawn with the robot's scenario RNG, of which the checkpoint's twin critics choose the
    /// one with the highest min(Q₁, Q₂) — a one-step policy improvement at test time, using the
    /// critics training leaves beside the actor. Like `sample`, unused while a learning agent is
    /// in the world.
    pub candidates: usize,
    /// Where the k − 1 candidates come from (default the policy).
    pub candidates_from: CandidateSource,
}

/// Where `sac_policy`'s candidates beside tanh(μ) are drawn from.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CandidateSource {
    /// The tanh-Gaussian policy: actions near what the actor would do.
    #[default]
    Policy,
    /// Uniformly over [−1, 1]²: every motion the robot has, as the critics' warm-up data held.
    Uniform,
}

impl Default for SacPolicyParams {
    fn default() -> Self {
        Self { checkpoint: None, sample: false, candidates: 1, candidates_from: CandidateSource::Policy }
    }
}

/// More candidates than this cost more than the rest of a step and are surely a typo.
const MAX_CANDIDATES: usize = 1024;

impl StepParams for SacPolicyParams {
    /// Loads the policy once per process, so a missing or broken file fails when the schedule
    /// loads, naming it.
    fn check(&self) -> Result<(), String> {
        if !(1..=MAX_CANDIDATES).contains(&self.candidates) {
            return Err(format!(
                "candidates: expected 1 (tanh(μ) alone) to {MAX_CANDIDATES} actions per step, got {}",
                self.candidates
            ));
        }
        if self.sample && self.candidates > 1 {
            return Err("sample and candidates > 1 both choose the action: set one of them".into());
        }
        match &self.checkpoint {
            Some(path) => shared_policy(path).map(|_| ()),
            None => Ok(()),
        }
    }
}

/// The networks in `path`, loaded once per process and shared by every world.
pub fn shared_policy(path: &str) -> Result<Arc<SacNetworks>, String> {
    static POLICIES: OnceLock<Mutex<HashMap<String, Arc<SacNetworks>>>> = OnceLock::new();
    let mut policies = POLICIES.get_or_init(Mutex::default).lock().unwrap_or_else(|p| p.into_inner());
    if let Some(policy) = policies.get(path) {
        return Ok(policy.clone());
    }
    let policy = Arc::new(SacNetworks::load(Path::new(path)).map_err(|e| format!("checkpoint: {e}"))?);
    policies.insert(path.to_string(), policy.clone());
    Ok(policy)
}

/// `Err` saying which step's field to set when the schedule's crops, grid or depth strip are not
/// the input of the policy `sac_policy` loads: checked when an eval config loads and whenever a
/// world is built (`plugin::check_policy_inputs`), so that a run fails before its first step
/// instead of writing results for robots that never moved.
pub fn check_policy_inputs(world: &World) -> Result<(), String> {
    let Some(path) = world.get_resource::<SacPolicyParams>().and_then(|p| p.checkpoint.clone()) else {
        return Ok(());
    };
    let net = shared_policy(&path)?.config.clone();
    let crop = world.get_resource::<BeliefParams>().cloned().unwrap_or_default();
    let channels = crop.channels();
    if (channels, crop.cells) != (net.belief_channels, net.belief_cells) {
        return Err(format!(
            "{path} reads {} belief crop(s) of {} cells ((modes + overview) × (1 + history)); belief_crop \
             gives {} of {} (modes: {}, overview_m: {:?}, history: {}): set its `modes`, `overview_m`, \
             `history` and `cells` to match",
            net.belief_channels / BELIEF_CHANNELS,
            net.belief_cells,
            channels / BELIEF_CHANNELS,
            crop.cells,
            crop.modes,
            crop.overview_m,
            crop.history
        ));
    }
    let grid_cells = world.get_resource::<LocalGridParams>().cloned().unwrap_or_default().out_cells;
    if grid_cells != net.grid_cells {
        return Err(format!(
            "{path} reads a {0}×{0} LiDAR grid; local_grid gives {1}×{1}: set its `out_cells` to {0}",
            net.grid_cells, grid_cells
        ));
    }
    let columns = world.get_resource::<DepthParams>().map(|d| d.columns);
    match (net.depth_columns, columns) {
        (0, _) => Ok(()),
        (n, Some(c)) if c == n => Ok(()),
        (n, _) => Err(format!(
            "{path} reads a depth strip of {n} columns; schedule the `depth` step with columns: {n}"
        )),
    }
}

/// Buffers kept across steps.
#[derive(Default)]
pub struct PolicyState {
    loaded: Option<Arc<SacNetworks>>,
    robots: Vec<Entity>,
    belief_bytes: Vec<u8>,
    grid_bytes: Vec<u8>,
    states: Vec<f32>,
    belief: Vec<f32>,
    grid: Vec<f32>,
    noise: Vec<f32>,
    actions: Vec<f32>,
    /// The replay ids of this step's observations (learning only).
    obs_ids: Vec<u64>,
    ws: PolicyWorkspace,
    warned: bool,
}

/// Fills `noise` with `draws` actions' random numbers for each of `order`'s robots, from its
/// ScenarioRng: standard normals, or with `uniform` actions in [−1, 1]. A robot spawned without
/// a ScenarioRng gets zeros (tanh(μ), or standing still among uniform candidates) and acts
/// deterministically, with one warning (`warned`).
fn draw_action_noise(
    robots: &mut Query<RobotView>,
    order: &[Entity],
    (draws, uniform): (usize, bool),
    noise: &mut Vec<f32>,
    warned: &mut bool,
) {
    noise.clear();
    for &robot in order {
        let Some(mut rng) = robots.get_mut(robot).expect("listed above").9 else {
            if !*warned {
                tracing::warn!(
                    "sac_policy: drawn actions need each robot's ScenarioRng; {robot:?} has none: zeros instead"
                );
                *warned = true;
            }
            noise.extend(std::iter::repeat_n(0.0, draws * ACTION_LEN));
            continue;
        };
        let rng = &mut rng.0;
        noise.extend((0..draws * ACTION_LEN).map(|_| {
            if uniform { rng.random_range(-1.0..=1.0) } else { rng.sample::<f32, _>(StandardNormal) }
        }));
    }
}

type RobotView<'a> = (
    (Entity, &'a RobotId),
    &'a BeliefCrop,
    &'a LocalGrid,
    Option<&'a DepthStrip>,
    &'a Collided,
    &'a Episode,
    Has<EpisodeEnd>,
    &'a Reward,
    &'a mut Action,
    Option<&'a mut ScenarioRng>,
);

/// Reads BeliefCrop, LocalGrid, DepthStrip (when the network reads one), Collided, Episode,
/// EpisodeEnd, Reward, the last Action, RobotId (the batch order), the learning agent (if any),
/// ScenarioRng (with `sample`). Writes Action; with a learning agent, its replay buffer.
pub fn sac_policy(
    params: Res<SacPolicyParams>,
    episode: Res<EpisodeParams>,
    depth_params: Option<Res<DepthParams>>,
    mut agents: Query<&mut SacAgent>,
    mut robots: Query<RobotView>,
    mut state: Local<PolicyState>,
) {
    let state = &mut *state;
    let mut agent = agents.single_mut().ok();
    if agent.is_none() && state.loaded.is_none() {
        match params.checkpoint.as_deref().map(shared_policy) {
            Some(Ok(policy)) => state.loaded = Some(policy),
            Some(Err(e)) => return tracing::warn!("sac_policy: {e}"),
            None => {
                return tracing::warn!("sac_policy: no checkpoint and no learning agent; robots keep still");
            }
        }
    }
    // A stable order, so batches (and random draws) do not depend on archetype layout.
    state.robots = in_id_order(robots.iter().map(|r| r.0));
    let n = state.robots.len();
    let shape = {
        let nets = agent
            .as_ref()
            .map_or_else(|| state.loaded.as_deref().expect("loaded above"), |a| &a.learner.nets);
        ObservationShape::of(&nets.config)
    };
    let (bl, gl, sl) = (shape.belief_len(), shape.grid_len(), shape.state_len());
    state.belief_bytes.resize(n * bl, 0);
    state.grid_bytes.resize(n * gl, 0);
    state.states.resize(n * sl, 0.0);
    state.obs_ids.clear();
    for (k, &robot) in state.robots.iter().enumerate() {
        let (_, crop, grid, depth, collided, ep, is_end, reward, action, _) =
            robots.get(robot).expect("listed above");
        let row = &mut state.states[k * sl..(k + 1) * sl];
        row[..STATE_LEN].copy_from_slice(&robot_state(action, collided.0, ep, episode.steps));
        let encoded = encode_belief(crop, &shape, &mut state.belief_bytes[k * bl..(k + 1) * bl])
            .and_then(|()| encode_grid(grid, &shape, &mut state.grid_bytes[k * gl..(k + 1) * gl]))
            .and_then(|()| encode_depth(depth, depth_params.as_deref(), &shape, &mut row[STATE_LEN..]));
        if let Err(e) = encoded {
            if !state.warned {
                tracing::error!("sac_policy: {e}");
                state.warned = true;
            }
            return;
        }
        if let Some(agent) = agent.as_deref_mut() {
            let (belief, grid) =
                (&state.belief_bytes[k * bl..(k + 1) * bl], &state.grid_bytes[k * gl..(k + 1) * gl]);
            let s = &state.states[k * sl..(k + 1) * sl];
            state.obs_ids.push(store(agent, robot, belief, grid, s, reward, is_end));
        }
    }

    state.belief.resize(n * bl, 0.0);
    state.grid.resize(n * gl, 0.0);
    decode(&state.belief_bytes, &mut state.belief);
    decode(&state.grid_bytes, &mut state.grid);
    state.actions.resize(n * ACTION_LEN, 0.0);
    let obs = Observations { n, belief: &state.belief, grid: &state.grid, state: &state.states };
    match agent.as_deref_mut() {
        Some(agent) if agent.warming_up() => {
            state.actions.iter_mut().for_each(|a| *a = agent.rng.random_range(-1.0..=1.0));
        }
        Some(agent) => {
            state.noise.clear();
            state.noise.extend((0..n * ACTION_LEN).map(|_| agent.rng.sample::<f32, _>(StandardNormal)));
            agent.learner.nets.act(&obs, Some(&state.noise), &mut state.ws, &mut state.actions);
        }
        None => {
            let policy = state.loaded.as_ref().expect("loaded above");
            let draws = if params.sample { 1 } else { params.candidates - 1 };
            let uniform = params.candidates_from == CandidateSource::Uniform;
            if draws > 0 {
                let (order, noise) = (&state.robots, &mut state.noise);
                draw_action_noise(&mut robots, order, (draws, uniform), noise, &mut state.warned);
            }
            if params.candidates > 1 {
                let others =
                    if uniform { Candidates::Given(&state.noise) } else { Candidates::Drawn(&state.noise) };
                policy.act_by_critics(&obs, others, &mut state.ws, &mut state.actions)
            } else {
                let noise = params.sample.then_some(&state.noise[..]);
                policy.act(&obs, noise, &mut state.ws, &mut state.actions)
            }
        }
    }
    for (k, &robot) in state.robots.iter().enumerate() {
        let (.., is_end, _, mut action, _) = robots.get_mut(robot).expect("listed above");
        let a = [state.actions[2 * k], state.actions[2 * k + 1]];
        *action = Action::new(a[0], a[1]);
        if let Some(agent) = agent.as_deref_mut()
            && !is_end
        {
            // The observation just stored is the one this action was chosen on.
            agent.pending.insert(robot, Pending { obs: state.obs_ids[k], action: a });
        }
    }
}

/// Stores a robot's observation and the transition its last action completes; returns the
/// observation's id.
fn store(
    agent: &mut SacAgent,
    robot: Entity,
    belief: &[u8],
    grid: &[u8],
    s: &[f32],
    reward: &Reward,
    is_end: bool,
) -> u64 {
    let id = agent.replay.push_observation(belief, grid, s);
    if let (Some(pending), Some(r)) = (agent.pending.remove(&robot), reward.0) {
        agent.replay.push(pending.obs, pending.action, r, id, is_end);
        agent.transitions += 1;
        *agent.returns.entry(robot).or_default() += r;
        if is_end {
            let total = agent.returns.remove(&robot).unwrap_or(r);
            agent.finished.push(EpisodeReturn { total, final_loss: -r });
        }
    }
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::agent::sac::SacAgentConfig;
    use crate::nn::sac::{SacHyper, SacNetConfig};
    use bevy::ecs::system::RunSystemOnce;

    /// Robot 0 with the observations the policy reads and a fresh episode.
    fn spawn_robot(world: &mut World, crop: BeliefCrop, grid: LocalGrid) -> Entity {
        let episode = (Collided(false), Episode::default(), Reward(None), Action::default());
        world.spawn((RobotId(0), crop, grid, episode)).id()
    }

    /// One robot through a 3-step episode and into the next, with a learning agent.
    #[test]
    fn every_action_gets_its_reward_and_the_last_step_ends_the_episode() {
        let mut world = World::new();
        world.insert_resource(SacPolicyParams::default());
        world.insert_resource(EpisodeParams { steps: 3, change_maps: false });
        let config = SacAgentConfig { buffer: 10, batch: 1, learning_starts: 0, hyper: SacHyper::default() };
        let agent = world.spawn(SacAgent::new(&SacNetConfig::tiny(), config, 1, 3, 7)).id();
        let crop = BeliefCrop { cells: 5, centres: vec![], values: vec![0.5; 100] };
        let grid = LocalGrid { cells: 5, extent_m: 5.0, values: vec![1.0; 25], wide: None };
        let robot = spawn_robot(&mut world, crop, grid);
        // (episode step, reward of the last action, last step?)
        let frames = [
            (1, None, false),
            (2, Some(-0.5), false),
            (3, Some(-0.25), true),
            (1, None, false),
            (2, Some(-1.0), false),
        ];
        for (step, reward, end) in frames {
            let mut r = world.entity_mut(robot);
            r.insert((Episode { index: 0, step }, Reward(reward)));
            if end {
                r.insert(EpisodeEnd);
            } else {
                r.remove::<EpisodeEnd>();
            }
            world.run_system_once(sac_policy).unwrap();
            let a = *world.get::<Action>(robot).unwrap();
            assert!(a.linear.abs() <= 1.0 && a.angular.abs() <= 1.0, "actions stay in [−1, 1]: {a:?}");
        }
        let agent = world.get::<SacAgent>(agent).unwrap();
        assert_eq!(agent.transitions, 3, "two actions of episode 1 and the first of episode 2");
        assert_eq!(agent.finished.len(), 1);
        assert_eq!(agent.finished[0].total, -0.75, "the last action's reward counts");
        assert_eq!(agent.finished[0].final_loss, 0.25);
        let mut batch = crate::agent::sac::SampledBatch::default();
        agent.replay.sample(&[0, 1, 2], &mut batch);
        let t = batch.transitions();
        assert_eq!(t.rewards, &[-0.5, -0.25, -1.0]);
        assert_eq!(t.dones, &[0.0, 1.0, 0.0], "the episode ends with its last step");
        assert_eq!(t.next_obs.state[4 + 3], 0.0, "no action left after the last step");
        assert!(agent.pending.contains_key(&robot), "the newest action waits for its reward");
    }

    #[test]
    fn a_checkpoint_policy_acts_deterministically_or_samples_and_a_bad_path_is_named() {
        let nets = SacNetworks::new(&SacNetConfig::tiny(), 3);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("policy.safetensors");
        nets.save(&path).unwrap();
        let params = SacPolicyParams { checkpoint: Some(path.display().to_string()), ..Default::default() };
        assert_eq!(params.check(), Ok(()));
        // `seed: None` spawns the robot without a ScenarioRng.
        let run_with = |params: SacPolicyParams, seed: Option<u64>| {
            let mut world = World::new();
            world.insert_resource(params);
            world.insert_resource(EpisodeParams::default());
            let crop = BeliefCrop {
                cells: 5,
                centres: vec![],
                values: (0..100).map(|i| (i % 7) as f32 / 7.0).collect(),
            };
            let grid = LocalGrid { cells: 5, extent_m: 5.0, values: vec![0.5; 25], wide: None };
            let robot = spawn_robot(&mut world, crop, grid);
            if let Some(seed) = seed {
                world.entity_mut(robot).insert(ScenarioRng::seeded(seed));
            }
            world.run_system_once(sac_policy).unwrap();
            *world.get::<Action>(robot).unwrap()
        };
        let run =
            |sample: bool, seed: Option<u64>| run_with(SacPolicyParams { sample, ..params.clone() }, seed);
        assert_eq!(run(false, Some(1)), run(false, Some(2)), "evaluation actions are tanh(μ), no noise");
        let drawn = run(true, Some(1));
        assert_eq!(drawn, run(true, Some(1)), "a drawn action is the robot's RNG's");
        assert_ne!(drawn, run(true, Some(2)), "another seed, another draw");
        assert_ne!(drawn, run(false, Some(1)), "a draw is not the mean action");
        assert!(drawn.linear.abs() <= 1.0 && drawn.angular.abs() <= 1.0, "drawn actions stay in [−1, 1]");
        assert_eq!(run(true, None), run(false, Some(1)), "no ScenarioRng: tanh(μ), no panic");
        for candidates_from in [CandidateSource::Policy, CandidateSource::Uniform] {
            let chosen =
                |seed| run_with(SacPolicyParams { candidates: 16, candidates_from, ..params.clone() }, seed);
            assert_eq!(chosen(Some(1)), chosen(Some(1)), "the critics' choice among the robot RNG's draws");
            let a = chosen(Some(2));
            assert!(a.linear.abs() <= 1.0 && a.angular.abs() <= 1.0, "{candidates_from:?}: {a:?}");
        }
        let chosen = run_with(SacPolicyParams { candidates: 16, ..params.clone() }, None);
        assert_eq!(chosen, run(false, Some(1)), "no ScenarioRng: every draw is tanh(μ)");
        let missing =
            SacPolicyParams { checkpoint: Some("no/such/policy.safetensors".into()), ..Default::default() };
        assert!(missing.check().unwrap_err().contains("no/such/policy.safetensors"));
    }

    #[test]
    fn candidates_are_checked() {
        let with = |candidates, sample| SacPolicyParams { candidates, sample, ..Default::default() }.check();
        assert_eq!(with(1, true), Ok(()));
        assert_eq!(with(32, false), Ok(()));
        assert!(with(0, false).unwrap_err().starts_with("candidates: expected 1"));
        assert!(with(1_000_000, false).unwrap_err().contains("got 1000000"));
        assert!(with(8, true).unwrap_err().contains("set one of them"));
    }

    #[test]
    fn the_policy_inputs_are_checked_against_the_crop_grid_and_depth_steps() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("policy.safetensors");
        SacNetworks::new(&SacNetConfig { belief_channels: 8, depth_columns: 3, ..SacNetConfig::tiny() }, 3)
            .save(&path)
            .unwrap();
        let mut world = World::new();
        assert_eq!(check_policy_inputs(&world), Ok(()), "no checkpoint, nothing to check");
        world.insert_resource(SacPolicyParams {
            checkpoint: Some(path.display().to_string()),
            ..Default::default()
        });
        world.insert_resource(BeliefParams { cells: 5, history: 1, ..Default::default() });
        world.insert_resource(LocalGridParams { out_cells: 5, ..Default::default() });
        world.insert_resource(DepthParams { columns: 3, ..Default::default() });
        assert_eq!(check_policy_inputs(&world), Ok(()));
        world.insert_resource(BeliefParams { cells: 5, ..Default::default() });
        let err = check_policy_inputs(&world).unwrap_err();
        assert!(err.contains("reads 2 belief crop(s) of 5 cells") && err.contains("history: 0"), "{err}");
        world.insert_resource(BeliefParams { cells: 5, overview_m: Some(0.4), ..Default::default() });
        assert_eq!(check_policy_inputs(&world), Ok(()), "the overview is the second crop");
        world.insert_resource(BeliefParams { cells: 5, history: 1, ..Default::default() });
        world.insert_resource(LocalGridParams::default());
        let err = check_policy_inputs(&world).unwrap_err();
        assert!(err.contains("5×5 LiDAR grid") && err.contains("`out_cells` to 5"), "{err}");
        world.insert_resource(LocalGridParams { out_cells: 5, ..Default::default() });
        world.remove_resource::<DepthParams>();
        let err = check_policy_inputs(&world).unwrap_err();
        assert!(err.contains("`depth` step with columns: 3"), "{err}");
    }

    #[test]
    fn a_depth_reading_agent_stores_the_strip_after_the_state_and_asks_for_the_depth_step() {
        let config = SacNetConfig { depth_columns: 3, ..SacNetConfig::tiny() };
        let agent_config =
            SacAgentConfig { buffer: 10, batch: 1, learning_starts: 0, hyper: SacHyper::default() };
        let mut world = World::new();
        world.insert_resource(SacPolicyParams::default());
        world.insert_resource(EpisodeParams { steps: 3, change_maps: false });
        let agent = world.spawn(SacAgent::new(&config, agent_config, 1, 3, 7)).id();
        let crop = BeliefCrop { cells: 5, centres: vec![], values: vec![0.5; 100] };
        let robot = spawn_robot(
            &mut world,
            crop,
            LocalGrid { cells: 5, extent_m: 5.0, values: vec![1.0; 25], wide: None },
        );
        world.entity_mut(robot).insert(Episode { index: 0, step: 1 });
        world.run_system_once(sac_policy).unwrap();
        assert!(
            world.get::<SacAgent>(agent).unwrap().pending.is_empty(),
            "no strip: no action, nothing stored"
        );

        world.insert_resource(DepthParams { columns: 3, max_m: 2.0, ..Default::default() });
        world.entity_mut(robot).insert(DepthStrip { depths_m: vec![0.5, 1.0, 2.0] });
        world.run_system_once(sac_policy).unwrap();
        world.entity_mut(robot).insert((Episode { index: 0, step: 2 }, Reward(Some(-0.5))));
        world.run_system_once(sac_policy).unwrap();
        let agent = world.get::<SacAgent>(agent).unwrap();
        let mut batch = crate::agent::sac::SampledBatch::default();
        agent.replay.sample(&[0], &mut batch);
        let state = batch.transitions().obs.state;
        assert_eq!(state.len(), STATE_LEN + 3);
        assert_eq!(state[STATE_LEN..], [0.25, 0.5, 1.0], "depth / max_m after the robot state");
    }
}
