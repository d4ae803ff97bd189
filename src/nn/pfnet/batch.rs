//! Running PF-net over every particle of every robot at once: fixed chunks of particles on the
//! rayon pool, one reusable workspace per thread, results independent of the thread count
//! (each chunk's arithmetic is the same whichever thread runs it).

use super::feature_cache::FeatureBank;
use super::model::{PfNet, Workspace};
use crate::nn::buffers::sized;
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::Mutex;

/// Particles per parallel task: enough columns for the locally-connected products to run near
/// the GEMM's peak, few enough that a task's activations stay small.
pub const PARTICLE_CHUNK: usize = 128;
/// Particles the map encoder takes at once inside a task (its 64 × 28 × 28 activations per
/// particle are the largest buffers of the step).
pub const MAP_ENCODER_CHUNK: usize = 8;

/// One workspace per pool thread, reused across steps so the filter path allocates nothing
/// once warm.
#[derive(Debug, Default)]
pub struct Workspaces {
    slots: Vec<Mutex<Workspace>>,
    /// `log_likelihoods_banked`'s particles in crop order.
    crop_order: Mutex<CropOrder>,
}

impl Workspaces {
    /// One slot per thread of the current rayon pool (plus one for callers outside it).
    pub fn for_current_pool() -> Self {
        let slots = (0..=rayon::current_num_threads()).map(|_| Mutex::default()).collect();
        Self { slots, crop_order: Mutex::default() }
    }

    /// Runs `f` with the calling thread's workspace.
    pub(super) fn with<R>(&self, f: impl FnOnce(&mut Workspace) -> R) -> R {
        let slot = rayon::current_thread_index().map_or(self.slots.len() - 1, |i| i % self.slots.len());
        let mut ws = self.slots[slot].lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        f(&mut ws)
    }
}

/// Metres per strip of `CropOrder`: a first-stage crop spans 2.8 m, so particles a strip apart
/// still share most of their windows' rows.
const CROP_STRIP_M: f32 = 0.5;

/// The order in which `log_likelihoods_banked` crops its particles, and the particles in it: by
/// robot, bank orientation, strip of the map and x. A global belief's particles, taken as they
/// come, jump across the whole bank (hundreds of MB per map) from one crop to the next; in this
/// order consecutive crops read overlapping windows still in cache. Each particle's arithmetic
/// does not depend on its neighbours, so the order changes no value.
#[derive(Debug, Default)]
pub(super) struct CropOrder {
    /// (robot, orientation, strip, x in cm, particle), sorted.
    keys: Vec<(u32, usize, i32, i32, u32)>,
    poses: Vec<[f32; 3]>,
    owner: Vec<u32>,
    loglik: Vec<f32>,
}

impl CropOrder {
    /// Sorts `poses` (of robots `owner`, cropping `banks[owner[i]]`) into crop order.
    pub(super) fn sort(&mut self, poses: &[[f32; 3]], owner: &[u32], banks: &[Arc<FeatureBank>]) {
        self.keys.clear();
        self.keys.extend(poses.iter().zip(owner).enumerate().map(|(i, (&[x, y, yaw], &robot))| {
            // `as` saturates, and sends a NaN coordinate to 0: any place in the order will do.
            let (strip, centimetres) = ((y / CROP_STRIP_M).floor() as i32, (x * 100.0).floor() as i32);
            (robot, banks[robot as usize].orientation_of(yaw), strip, centimetres, i as u32)
        }));
        self.keys.sort_unstable(); // every key differs in its particle, so the order is total
        self.poses.clear();
        self.poses.extend(self.keys.iter().map(|key| poses[key.4 as usize]));
        self.owner.clear();
        self.owner.extend(self.keys.iter().map(|key| key.0));
    }

    /// Whether the order differs from the particles' own.
    #[cfg(test)]
    pub(super) fn moves_any(&self) -> bool {
        self.keys.iter().enumerate().any(|(k, key)| key.4 as usize != k)
    }
}

impl PfNet {
    /// Observation terms for `n` observations ([n][obs_len] → [n][obs_term_len]), one per task.
    pub fn observation_terms_par(&self, obs: &[f32], terms: &mut [f32], pool: &Workspaces) {
        let (len, tlen) = (self.obs_len(), self.obs_term_len());
        terms.par_chunks_mut(tlen).zip(obs.par_chunks(len)).for_each(|(out, one)| {
            pool.with(|ws| self.observation_terms(one, 1, out, ws));
        });
    }

    /// Map features of every particle from its local map ([n][local_map_len] → [n][map_feature_len]):
    /// the per-particle half of the exact path, and what the feature cache stores per map.
    pub fn encode_local_maps_par(&self, maps: &[f32], features: &mut [f32], pool: &Workspaces) {
        let (len, flen) = (self.local_map_len(), self.map_feature_len());
        features
            .par_chunks_mut(MAP_ENCODER_CHUNK * flen)
            .zip(maps.par_chunks(MAP_ENCODER_CHUNK * len))
            .for_each(|(out, chunk)| {
                pool.with(|ws| self.encode_local_maps(chunk, chunk.len() / len, out, ws));
            });
    }

    /// Log-likelihoods of every particle from its local map (the paper's exact path): particle
    /// i belongs to robot `owner[i]`, whose observation terms are row `owner[i]` of `obs_terms`.
    pub fn log_likelihoods_exact(
        &self,
        obs_terms: &[f32],
        owner: &[u32],
        maps: &[f32],
        loglik: &mut [f32],
        pool: &Workspaces,
    ) {
        let (len, flen) = (self.local_map_len(), self.map_feature_len());
        loglik.par_chunks_mut(PARTICLE_CHUNK).enumerate().for_each(|(c, out)| {
            let first = c * PARTICLE_CHUNK;
            let maps = &maps[first * len..(first + out.len()) * len];
            pool.with(|ws| {
                let mut features = std::mem::take(&mut ws.chunk_map_features);
                features.resize(out.len() * flen, 0.0);
                for (sub, part) in
                    maps.chunks(MAP_ENCODER_CHUNK * len).zip(features.chunks_mut(MAP_ENCODER_CHUNK * flen))
                {
                    self.encode_local_maps(sub, sub.len() / len, part, ws);
                }
                let owners = &owner[first..first + out.len()];
                self.joint_log_likelihoods(&features, obs_terms, owners, out, ws);
                ws.chunk_map_features = features;
            });
        });
    }

    /// Scan terms of `n` observations ([n][obs_len] → [n][scan_term_len]), one per task.
    pub fn scan_terms_par(&self, obs: &[f32], terms: &mut [f32], pool: &Workspaces) {
        let (len, tlen) = (self.obs_len(), self.scan_term_len());
        terms.par_chunks_mut(tlen).zip(obs.par_chunks(len)).for_each(|(out, one)| {
            pool.with(|ws| self.scan_terms(one, out, ws));
        });
    }

    /// Log-likelihoods of every particle (world x, y, yaw in `poses`) from the first-stage banks
    /// of its robot's map (`banks[owner[i]]`) and that robot's scan terms (the cached path of a
    /// network laying the scan on its local maps), same ownership rule; cropped in `CropOrder`.
    pub fn log_likelihoods_banked(
        &self,
        (obs_terms, scan_terms): (&[f32], &[f32]),
        owner: &[u32],
        (poses, banks): (&[[f32; 3]], &[Arc<FeatureBank>]),
        loglik: &mut [f32],
        pool: &Workspaces,
    ) {
        let flen = self.map_feature_len();
        let mut order = pool.crop_order.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        order.sort(poses, owner, banks);
        let CropOrder { keys, poses, owner, loglik: sorted } = &mut *order;
        let (poses, owner) = (&poses[..], &owner[..]);
        sized(sorted, loglik.len());
        sorted.par_chunks_mut(PARTICLE_CHUNK).enumerate().for_each(|(c, out)| {
            let first = c * PARTICLE_CHUNK;
            let (poses, owners) = (&poses[first..first + out.len()], &owner[first..first + out.len()]);
            pool.with(|ws| {
                let mut features = std::mem::take(&mut ws.chunk_map_features);
                features.resize(out.len() * flen, 0.0);
                let subs = poses.chunks(MAP_ENCODER_CHUNK).zip(owners.chunks(MAP_ENCODER_CHUNK));
                for ((poses, sub_owners), part) in subs.zip(features.chunks_mut(MAP_ENCODER_CHUNK * flen)) {
                    self.encode_banked((poses, sub_owners), (banks, scan_terms), part, ws);
                }
                self.joint_log_likelihoods(&features, obs_terms, owners, out, ws);
                ws.chunk_map_features = features;
            });
        });
        for (key, &value) in keys.iter().zip(sorted.iter()) {
            loglik[key.4 as usize] = value;
        }
    }

    /// Log-likelihoods from map features already at hand (the cached path), same ownership rule.
    pub fn log_likelihoods_from_features(
        &self,
        obs_terms: &[f32],
        owner: &[u32],
        map_features: &[f32],
        loglik: &mut [f32],
        pool: &Workspaces,
    ) {
        let flen = self.map_feature_len();
        loglik.par_chunks_mut(PARTICLE_CHUNK).enumerate().for_each(|(c, out)| {
            let first = c * PARTICLE_CHUNK;
            let features = &map_features[first * flen..(first + out.len()) * flen];
            let owners = &owner[first..first + out.len()];
            pool.with(|ws| self.joint_log_likelihoods(features, obs_terms, owners, out, ws));
        });
    }
}
