//! The replay buffer: transitions (s, a, r, s′, d) in a ring, observations stored once each in a
//! second ring of bytes (a transition names its two observations), so a transition costs one
//! observation's bytes, not two. Paper-size inputs: 50 × 50 × 4 + 56 × 56 bytes + 16 bytes of
//! state ≈ 13.2 kB per observation, ≈ 0.67 GB for 50,000 transitions.

use crate::agent::sac::observation::{ObservationShape, decode};
use crate::nn::sac::{ACTION_LEN, Observations, Transitions};
use crate::world::map::write_atomically;
use anyhow::Context;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct ReplayBuffer {
    shape: ObservationShape,
    obs_capacity: usize,
    /// Observations written so far; observation `id` lives in slot `id % obs_capacity`.
    obs_written: u64,
    belief: Vec<u8>,
    grid: Vec<u8>,
    state: Vec<f32>,
    capacity: usize,
    /// Transitions written so far; the ring keeps the last `capacity`.
    written: u64,
    obs: Vec<u64>,
    next_obs: Vec<u64>,
    actions: Vec<f32>,
    rewards: Vec<f32>,
    dones: Vec<f32>,
}

/// A sampled minibatch decoded to network inputs; buffers reused from batch to batch.
#[derive(Clone, Debug, Default)]
pub struct SampledBatch {
    n: usize,
    belief: [Vec<f32>; 2],
    grid: [Vec<f32>; 2],
    state: [Vec<f32>; 2],
    actions: Vec<f32>,
    rewards: Vec<f32>,
    dones: Vec<f32>,
}

impl SampledBatch {
    pub fn transitions(&self) -> Transitions<'_> {
        let obs = |i: usize| Observations {
            n: self.n,
            belief: &self.belief[i],
            grid: &self.grid[i],
            state: &self.state[i],
        };
        Transitions {
            obs: obs(0),
            actions: &self.actions,
            rewards: &self.rewards,
            dones: &self.dones,
            next_obs: obs(1),
        }
    }
}

impl ReplayBuffer {
    /// Room for `capacity` transitions from episodes of `episode_steps` observations, collected
    /// by `robots` robots at once: each episode's first observation starts no transition, and
    /// every robot's latest observation still waits for its successor.
    pub fn new(capacity: usize, episode_steps: usize, robots: usize, shape: ObservationShape) -> Self {
        let obs_capacity =
            capacity + capacity.div_ceil(episode_steps.saturating_sub(1).max(1)) + 2 * robots + 1;
        Self {
            shape,
            obs_capacity,
            obs_written: 0,
            belief: vec![0; obs_capacity * shape.belief_len()],
            grid: vec![0; obs_capacity * shape.grid_len()],
            state: vec![0.0; obs_capacity * shape.state_len()],
            capacity,
            written: 0,
            obs: vec![0; capacity],
            next_obs: vec![0; capacity],
            actions: vec![0.0; capacity * ACTION_LEN],
            rewards: vec![0.0; capacity],
            dones: vec![0.0; capacity],
        }
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.written.min(self.capacity as u64) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.written == 0
    }

    /// Bytes held by the buffer's arrays.
    pub fn memory_bytes(&self) -> usize {
        self.belief.len()
            + self.grid.len()
            + 4 * self.state.len()
            + 16 * self.capacity
            + 4 * self.actions.len()
            + 8 * self.capacity
    }

    /// Stores an observation; returns its id for [`ReplayBuffer::push`].
    /// `state` is the robot state ⊕ depth strip (`shape.state_len()` floats).
    pub fn push_observation(&mut self, belief: &[u8], grid: &[u8], state: &[f32]) -> u64 {
        let (bl, gl, sl) = (self.shape.belief_len(), self.shape.grid_len(), self.shape.state_len());
        let slot = (self.obs_written % self.obs_capacity as u64) as usize;
        self.belief[slot * bl..(slot + 1) * bl].copy_from_slice(belief);
        self.grid[slot * gl..(slot + 1) * gl].copy_from_slice(grid);
        self.state[slot * sl..(slot + 1) * sl].copy_from_slice(state);
        self.obs_written += 1;
        self.obs_written - 1
    }

    /// Stores a transition between two stored observations, overwriting the oldest when full.
    pub fn push(&mut self, obs: u64, action: [f32; ACTION_LEN], reward: f32, next_obs: u64, done: bool) {
        let i = (self.written % self.capacity as u64) as usize;
        self.obs[i] = obs;
        self.next_obs[i] = next_obs;
        self.actions[i * ACTION_LEN..(i + 1) * ACTION_LEN].copy_from_slice(&action);
        self.rewards[i] = reward;
        self.dones[i] = f32::from(u8::from(done));
        self.written += 1;
    }

    /// Decodes the transitions at ring positions `indices` (each `< len()`) into `out`.
    pub fn sample(&self, indices: &[usize], out: &mut SampledBatch) {
        let (bl, gl, n) = (self.shape.belief_len(), self.shape.grid_len(), indices.len());
        let sl = self.shape.state_len();
        out.n = n;
        for (side, ids) in [&self.obs, &self.next_obs].into_iter().enumerate() {
            out.belief[side].resize(n * bl, 0.0);
            out.grid[side].resize(n * gl, 0.0);
            out.state[side].resize(n * sl, 0.0);
            for (k, &i) in indices.iter().enumerate() {
                let id = ids[i];
                assert!(
                    self.obs_written - id <= self.obs_capacity as u64,
                    "replay: observation {id} was overwritten"
                );
                let slot = (id % self.obs_capacity as u64) as usize;
                decode(&self.belief[slot * bl..(slot + 1) * bl], &mut out.belief[side][k * bl..(k + 1) * bl]);
                decode(&self.grid[slot * gl..(slot + 1) * gl], &mut out.grid[side][k * gl..(k + 1) * gl]);
                out.state[side][k * sl..(k + 1) * sl]
                    .copy_from_slice(&self.state[slot * sl..(slot + 1) * sl]);
            }
        }
        out.actions.clear();
        out.rewards.clear();
        out.dones.clear();
        for &i in indices {
            out.actions.extend_from_slice(&self.actions[i * ACTION_LEN..(i + 1) * ACTION_LEN]);
            out.rewards.push(self.rewards[i]);
            out.dones.push(self.dones[i]);
        }
    }
}

/// Every array of a buffer by name, as little-endian bytes: the replay file's tensors.
fn arrays(b: &ReplayBuffer) -> Vec<(&'static str, Vec<u8>)> {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let u64s = |v: &[u64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    vec![
        ("counts", u64s(&[b.obs_capacity as u64, b.obs_written, b.capacity as u64, b.written])),
        ("belief", b.belief.clone()),
        ("grid", b.grid.clone()),
        ("state", f32s(&b.state)),
        ("obs", u64s(&b.obs)),
        ("next_obs", u64s(&b.next_obs)),
        ("actions", f32s(&b.actions)),
        ("rewards", f32s(&b.rewards)),
        ("dones", f32s(&b.dones)),
    ]
}

impl ReplayBuffer {
    /// Writes the buffer atomically as a safetensors file of byte tensors.
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let arrays = arrays(self);
        let views = arrays
            .iter()
            .map(|(name, bytes)| Ok((*name, TensorView::new(Dtype::U8, vec![bytes.len()], bytes)?)))
            .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
        let bytes = safetensors::serialize(views, None)?;
        write_atomically(path, &bytes)?;
        Ok(())
    }

    /// Reads a buffer [`ReplayBuffer::save`] wrote; it must match `shape` and the sizes of `like`.
    pub fn load(path: &Path, like: &ReplayBuffer) -> anyhow::Result<Self> {
        let bytes =
            std::fs::read(path).with_context(|| format!("reading replay buffer {}", path.display()))?;
        let file = SafeTensors::deserialize(&bytes)
            .with_context(|| format!("{}: not a replay buffer", path.display()))?;
        let mut loaded = like.clone();
        let expected = arrays(like);
        let tensor = |name: &str| -> anyhow::Result<Vec<u8>> {
            let t = file
                .tensor(name)
                .with_context(|| format!("{}: tensor `{name}` is missing", path.display()))?;
            let want = expected.iter().find(|(n, _)| *n == name).map_or(0, |(_, b)| b.len());
            anyhow::ensure!(
                t.data().len() == want,
                "{}: tensor `{name}` has {} bytes, expected {want} (a buffer of another size or network)",
                path.display(),
                t.data().len()
            );
            Ok(t.data().to_vec())
        };
        let f32s = |b: Vec<u8>| {
            b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes"))).collect()
        };
        let u64s = |b: Vec<u8>| -> Vec<u64> {
            b.chunks_exact(8).map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes"))).collect()
        };
        let counts = u64s(tensor("counts")?);
        anyhow::ensure!(
            counts[0] == like.obs_capacity as u64 && counts[2] == like.capacity as u64,
            "{}: a buffer of another capacity",
            path.display()
        );
        (loaded.obs_written, loaded.written) = (counts[1], counts[3]);
        loaded.belief = tensor("belief")?;
        loaded.grid = tensor("grid")?;
        loaded.state = f32s(tensor("state")?);
        loaded.obs = u64s(tensor("obs")?);
        loaded.next_obs = u64s(tensor("next_obs")?);
        loaded.actions = f32s(tensor("actions")?);
        loaded.rewards = f32s(tensor("rewards")?);
        loaded.dones = f32s(tensor("dones")?);
        // A damaged id would fail `sample`'s assertion hours into the resumed run: check every
        // live transition's observations now.
        for (i, &id) in loaded.obs[..loaded.len()].iter().chain(&loaded.next_obs[..loaded.len()]).enumerate()
        {
            anyhow::ensure!(
                id < loaded.obs_written && loaded.obs_written - id <= loaded.obs_capacity as u64,
                "{}: tensor `{}`: observation {id} at {}, expected one of the last {} of the {} written",
                path.display(),
                if i < loaded.len() { "obs" } else { "next_obs" },
                i % loaded.len(),
                loaded.obs_capacity,
                loaded.obs_written
            );
        }
        Ok(loaded)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape() -> ObservationShape {
        ObservationShape { belief_cells: 1, belief_channels: 4, grid_cells: 1, depth_columns: 0 }
    }

    /// Stores observation `k` with every byte `k` and state `[k, 0, 0, 0]`.
    fn observe(buffer: &mut ReplayBuffer, k: u8) -> u64 {
        buffer.push_observation(&[k; 4], &[k], &[f32::from(k), 0.0, 0.0, 0.0])
    }

    #[test]
    fn ring_wraps_around_and_keeps_the_newest_transitions() {
        // 3 robots, episodes of 4 observations (3 transitions), room for 5 transitions.
        let mut buffer = ReplayBuffer::new(5, 4, 3, shape());
        let mut last = [None; 3];
        let mut pushed = Vec::new();
        for step in 0..8u8 {
            for robot in 0..3u8 {
                let k = step * 3 + robot;
                let id = observe(&mut buffer, k);
                if let Some((prev, prev_k)) = last[robot as usize]
                    && step % 4 != 0
                {
                    buffer.push(prev, [f32::from(prev_k), 0.0], f32::from(k), id, step % 4 == 3);
                    pushed.push((prev_k, k));
                }
                last[robot as usize] = Some((id, k));
            }
        }
        assert_eq!(buffer.len(), 5, "full at capacity");
        let mut batch = SampledBatch::default();
        buffer.sample(&[0, 1, 2, 3, 4], &mut batch);
        let t = batch.transitions();
        let mut got: Vec<(u8, u8)> = (0..5).map(|k| (t.actions[2 * k] as u8, t.rewards[k] as u8)).collect();
        got.sort_unstable();
        let mut want = pushed[pushed.len() - 5..].to_vec();
        want.sort_unstable();
        assert_eq!(got, want, "the five newest transitions survive the wrap");
        for k in 0..5 {
            // Each transition's observations are the ones stored with it, bytes intact.
            assert_eq!(t.obs.state[4 * k], t.actions[2 * k], "s matches its action's step");
            assert_eq!(t.next_obs.state[4 * k], t.rewards[k], "s′ matches");
            assert_eq!(t.obs.grid[k], t.actions[2 * k] / 255.0);
        }
    }

    #[test]
    fn save_and_load_round_trip() {
        let mut buffer = ReplayBuffer::new(4, 3, 1, shape());
        let (a, b) = (observe(&mut buffer, 1), observe(&mut buffer, 2));
        buffer.push(a, [0.5, -0.5], -0.25, b, true);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("replay.safetensors");
        buffer.save(&path).unwrap();
        let empty = ReplayBuffer::new(4, 3, 1, shape());
        assert_eq!(ReplayBuffer::load(&path, &empty).unwrap(), buffer);
        let other = ReplayBuffer::new(8, 3, 1, shape());
        let err = ReplayBuffer::load(&path, &other).unwrap_err().to_string();
        assert!(err.contains("replay.safetensors"), "{err}");

        let mut damaged = buffer.clone();
        damaged.next_obs[0] = 7;
        damaged.save(&path).unwrap();
        let err = ReplayBuffer::load(&path, &empty).unwrap_err().to_string();
        assert!(
            err.ends_with(
                "tensor `next_obs`: observation 7 at 0, expected one of the last 9 of the 2 written"
            ),
            "{err}"
        );
    }
}
