//! Transition (motion update): each particle applies the robot's odometry delta in its own frame,
//! perturbed by Gaussian noise, as in PF-net's transition model.

use crate::params::{StepParams, expect_param};
use crate::particles::set::ParticleSet;
use crate::sense::Odometry;
use crate::world::rng::stream;
use crate::world::{FilterRng, Pose2};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Particles per noise stream. Fixed, so results do not depend on the thread count.
pub const TRANSITION_CHUNK: usize = 256;

/// Noise added to the odometry delta of every particle.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TransitionParams {
    /// Std-dev of the translation noise on each of Δx, Δy, metres (paper RL/eval: 0.01; 0 in PF-net pretraining).
    pub trans_noise_m: f32,
    /// Std-dev of the heading noise on Δyaw, degrees (paper RL/eval: 5; 0 in PF-net pretraining).
    pub rot_noise_deg: f32,
}

impl Default for TransitionParams {
    fn default() -> Self {
        Self { trans_noise_m: 0.01, rot_noise_deg: 5.0 }
    }
}

impl StepParams for TransitionParams {
    fn check(&self) -> Result<(), String> {
        let std_dev = |x: f32| x >= 0.0 && x.is_finite();
        expect_param(std_dev(self.trans_noise_m), "trans_noise_m", "a std-dev ≥ 0 m")?;
        expect_param(std_dev(self.rot_noise_deg), "rot_noise_deg", "a std-dev ≥ 0°")
    }
}

impl TransitionParams {
    /// `delta` plus N(0, σ) noise on (Δx, Δy, Δyaw); negative sigmas are read as their magnitude.
    /// Without noise (PF-net pretraining, infogain's reach plans) nothing is drawn from `rng`.
    pub fn noisy(&self, delta: &Pose2, rng: &mut impl Rng) -> Pose2 {
        let sigma_t = self.trans_noise_m.abs();
        let sigma_r = self.rot_noise_deg.abs().to_radians();
        if sigma_t == 0.0 && sigma_r == 0.0 {
            return *delta;
        }
        Pose2::new(
            delta.x + sigma_t * rng.sample::<f32, _>(StandardNormal),
            delta.y + sigma_t * rng.sample::<f32, _>(StandardNormal),
            delta.yaw + sigma_r * rng.sample::<f32, _>(StandardNormal),
        )
    }
}

/// Moves every particle by `delta` (robot frame) plus N(0, σ) noise on (Δx, Δy, Δyaw)
/// (`TransitionParams::noisy`). Noise for chunk c of `TRANSITION_CHUNK` particles comes from
/// `stream(&[key, c])`; chunks run in parallel.
pub fn propagate(set: &mut ParticleSet, delta: &Pose2, params: &TransitionParams, key: u64) {
    let ParticleSet { x, y, yaw, .. } = set;
    x.par_chunks_mut(TRANSITION_CHUNK)
        .zip(y.par_chunks_mut(TRANSITION_CHUNK))
        .zip(yaw.par_chunks_mut(TRANSITION_CHUNK))
        .enumerate()
        .for_each(|(chunk, ((xs, ys), yaws))| {
            let mut rng = stream(&[key, chunk as u64]);
            for ((px, py), pyaw) in xs.iter_mut().zip(ys.iter_mut()).zip(yaws.iter_mut()) {
                let noisy = params.noisy(delta, &mut rng);
                let moved = Pose2::new(*px, *py, *pyaw).compose(&noisy);
                (*px, *py, *pyaw) = (moved.x, moved.y, moved.yaw);
            }
        });
}

/// Reads Odometry (with the heading error a scan match narrowed, if any), TransitionParams.
/// Writes ParticleSet poses, FilterRng (one stream key per call).
pub fn transition(
    params: Res<TransitionParams>,
    mut robots: Query<(&Odometry, &mut ParticleSet, &mut FilterRng)>,
) {
    for (odometry, mut set, mut rng) in &mut robots {
        let key: u64 = rng.0.random();
        let narrowed =
            odometry.yaw_std_rad.map(|std| TransitionParams { rot_noise_deg: std.to_degrees(), ..*params });
        propagate(&mut set, &odometry.delta, narrowed.as_ref().unwrap_or(&params), key);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::angle_error;
    use bevy::ecs::system::RunSystemOnce;
    use std::f32::consts::FRAC_PI_2;

    #[test]
    fn transition_applies_delta_in_particle_frame() {
        let mut world = World::new();
        world.insert_resource(TransitionParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 });
        let set = ParticleSet::from_poses(&[Pose2::new(1.0, 1.0, FRAC_PI_2), Pose2::new(0.0, 0.0, 0.0)]);
        let odometry = Odometry { delta: Pose2::new(0.5, 0.0, 0.25), yaw_std_rad: None };
        let e = world.spawn((set, odometry, FilterRng::seeded(5))).id();
        world.run_system_once(transition).expect("transition runs");
        let set = world.get::<ParticleSet>(e).expect("set");
        assert!(
            (set.x[0] - 1.0).abs() < 1e-5 && (set.y[0] - 1.5).abs() < 1e-5,
            "facing +y moves +y: {set:?}"
        );
        assert!(angle_error(set.yaw[0], FRAC_PI_2 + 0.25) < 1e-5, "heading turns by Δyaw");
        assert!((set.x[1] - 0.5).abs() < 1e-5 && set.y[1].abs() < 1e-5, "facing +x moves +x: {set:?}");
    }

    #[test]
    fn transition_noise_has_requested_spread() {
        let mut set = ParticleSet::from_poses(&vec![Pose2::default(); 4000]);
        propagate(&mut set, &Pose2::default(), &TransitionParams::default(), 42);
        let std = |v: &[f32]| (v.iter().map(|a| a * a).sum::<f32>() / v.len() as f32).sqrt();
        let (sx, syaw) = (std(&set.x), std(&set.yaw).to_degrees());
        assert!((sx - 0.01).abs() < 0.001, "x spread should be ≈ 0.01 m, got {sx}");
        assert!((syaw - 5.0).abs() < 0.4, "yaw spread should be ≈ 5°, got {syaw}");
    }

    #[test]
    fn a_narrowed_heading_change_is_drawn_with_its_own_error() {
        let mut world = World::new();
        world.insert_resource(TransitionParams::default());
        let odometry = |yaw_std_rad| Odometry { delta: Pose2::default(), yaw_std_rad };
        let set = || ParticleSet::from_poses(&vec![Pose2::default(); 4000]);
        let wheels = world.spawn((set(), odometry(None), FilterRng::seeded(5))).id();
        let matched = world.spawn((set(), odometry(Some(0.5f32.to_radians())), FilterRng::seeded(5))).id();
        world.run_system_once(transition).expect("transition runs");
        let spread = |robot| {
            let yaw = &world.get::<ParticleSet>(robot).expect("set").yaw;
            (yaw.iter().map(|a| a * a).sum::<f32>() / yaw.len() as f32).sqrt().to_degrees()
        };
        let (wheels, matched) = (spread(wheels), spread(matched));
        assert!(
            (wheels - 5.0).abs() < 0.4 && (matched - 0.5).abs() < 0.04,
            "5° and 0.5°: {wheels}, {matched}"
        );
    }

    #[test]
    fn transition_is_independent_of_thread_count() {
        let start = ParticleSet::from_poses(&vec![Pose2::new(1.0, 2.0, 0.3); 3 * TRANSITION_CHUNK + 17]);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
            let mut set = start.clone();
            pool.install(|| propagate(&mut set, &Pose2::new(0.2, 0.0, 0.1), &TransitionParams::default(), 9));
            set
        };
        assert_eq!(run(1), run(3), "noise must depend on (key, chunk) only, never on threads");
    }
}
