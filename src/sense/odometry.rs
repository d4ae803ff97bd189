//! Odometry: the robot's motion since the previous agent step, in its previous frame, with noise.

use crate::params::{StepParams, expect_param};
use crate::world::{Pose2, PreviousPose, SensorRng, TruePose, wrap_angle};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// Relative motion reported by wheel odometry for the last agent step (robot frame, m and rad).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Odometry {
    pub delta: Pose2,
    /// Std-dev of `delta.yaw`'s error where a step after the wheels narrowed it (`scan_matching`),
    /// radians; `None`: the wheels' own, which the transition's parameters describe.
    pub yaw_std_rad: Option<f32>,
}

/// Gaussian noise on the reported motion, per agent step.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryParams {
    /// Std-dev on each of Δx and Δy, metres (paper: 0.01 in RL and evaluation, 0 in PF-net pretraining).
    pub trans_noise_m: f32,
    /// Std-dev on Δθ, degrees (paper: 5 in RL and evaluation, 0 in PF-net pretraining).
    pub rot_noise_deg: f32,
}

impl Default for OdometryParams {
    fn default() -> Self {
        Self { trans_noise_m: 0.01, rot_noise_deg: 5.0 }
    }
}

impl StepParams for OdometryParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.trans_noise_m >= 0.0, "trans_noise_m", "a std-dev ≥ 0 m")?;
        expect_param(self.rot_noise_deg >= 0.0, "rot_noise_deg", "a std-dev ≥ 0°")
    }
}

/// `previous⁻¹ ⊕ current` plus N(0, σ²) on x, y (σ_trans) and yaw (σ_rot), in that draw order:
/// the kernel of [`odometry`]. A zero σ draws nothing and leaves that component exact.
pub fn noisy_delta(previous: Pose2, current: Pose2, params: &OdometryParams, rng: &mut impl Rng) -> Pose2 {
    let mut delta = previous.between(&current);
    let mut noise = |std: f32| if std > 0.0 { std * rng.sample::<f32, _>(StandardNormal) } else { 0.0 };
    delta.x += noise(params.trans_noise_m);
    delta.y += noise(params.trans_noise_m);
    delta.yaw = wrap_angle(delta.yaw + noise(params.rot_noise_deg.to_radians()));
    delta
}

/// Reads TruePose, PreviousPose, SensorRng. Writes Odometry, PreviousPose (= TruePose).
pub fn odometry(
    params: Res<OdometryParams>,
    mut robots: Query<(&TruePose, &mut PreviousPose, &mut Odometry, &mut SensorRng)>,
) {
    for (pose, mut previous, mut odom, mut rng) in robots.iter_mut() {
        odom.delta = noisy_delta(previous.0, pose.0, &params, &mut rng.0);
        previous.0 = pose.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::angle_error;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn odometry_without_noise_composes_back_to_the_true_pose() {
        let mut world = World::new();
        world.insert_resource(OdometryParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 });
        let (before, after) = (Pose2::new(1.0, 2.0, 3.0), Pose2::new(1.3, 1.8, -2.9));
        let robot = world
            .spawn((TruePose(after), PreviousPose(before), Odometry::default(), SensorRng::seeded(1)))
            .id();
        world.run_system_once(odometry).unwrap();
        let delta = world.get::<Odometry>(robot).unwrap().delta;
        let back = before.compose(&delta);
        assert!(back.distance(&after) < 1e-5, "previous ⊕ delta = {back:?}, true pose {after:?}");
        assert!(angle_error(back.yaw, after.yaw) < 1e-5, "yaw across ±π: {back:?}");
        assert_eq!(world.get::<PreviousPose>(robot).unwrap().0, after, "previous pose advances");
    }

    #[test]
    fn odometry_noise_has_the_configured_spread() {
        let params = OdometryParams::default();
        let mut rng = SensorRng::seeded(2);
        let (p, q) = (Pose2::new(0.0, 0.0, 0.5), Pose2::new(0.0, 0.0, 0.5));
        let n = 20000;
        let draws: Vec<Pose2> = (0..n).map(|_| noisy_delta(p, q, &params, &mut rng.0)).collect();
        let std = |f: fn(&Pose2) -> f32| (draws.iter().map(|d| f(d).powi(2)).sum::<f32>() / n as f32).sqrt();
        let (sx, sy, syaw) = (std(|d| d.x), std(|d| d.y), std(|d| d.yaw));
        assert!((sx - 0.01).abs() < 5e-4 && (sy - 0.01).abs() < 5e-4, "σ_trans: {sx}, {sy}");
        assert!((syaw - 5f32.to_radians()).abs() < 0.003, "σ_rot: {syaw} rad");
    }
}
