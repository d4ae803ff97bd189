//! The pose estimate: weighted mean position, circular weighted mean heading, and the weighted
//! covariance of (x, y, yaw) with heading deviations wrapped.

use crate::particles::set::{ParticleSet, PoseEstimate};
use crate::world::{Pose2, circular_mean, wrap_angle};
use bevy::prelude::*;

/// Weighted mean and covariance of a set; `None` for an empty set. The heading is the circular
/// mean (the reference used a linear mean, which breaks near ±π — DESIGN §5).
pub fn estimate_pose(set: &ParticleSet) -> Option<PoseEstimate> {
    if set.is_empty() {
        return None;
    }
    let w = set.weights();
    let (mut mx, mut my, mut total) = (0.0f64, 0.0f64, 0.0f64);
    for ((&wk, &x), &y) in w.iter().zip(&set.x).zip(&set.y) {
        mx += wk as f64 * x as f64;
        my += wk as f64 * y as f64;
        total += wk as f64;
    }
    if total <= 0.0 || !total.is_finite() {
        return None;
    }
    let (mx, my) = (mx / total, my / total);
    let yaw = circular_mean(&set.yaw, &w);
    let mut cov = [[0.0f64; 3]; 3];
    for (((&wk, &x), &y), &a) in w.iter().zip(&set.x).zip(&set.y).zip(&set.yaw) {
        let d = [x as f64 - mx, y as f64 - my, wrap_angle(a - yaw) as f64];
        for (r, row) in cov.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v += wk as f64 * d[r] * d[c];
            }
        }
    }
    let cov = cov.map(|row| row.map(|v| (v / total) as f32));
    Some(PoseEstimate { pose: Pose2::new(mx as f32, my as f32, yaw), cov })
}

/// Reads ParticleSet. Writes PoseEstimate (left unchanged while the set is empty).
pub fn estimate(mut robots: Query<(&ParticleSet, &mut PoseEstimate)>) {
    robots.par_iter_mut().for_each(|(set, mut out)| {
        if let Some(e) = estimate_pose(set) {
            *out = e;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::angle_error;
    use bevy::ecs::system::RunSystemOnce;
    use std::f32::consts::PI;

    #[test]
    fn estimate_is_circular_across_pi() {
        let mut world = World::new();
        let poses = [Pose2::new(1.0, 2.0, PI - 0.1), Pose2::new(3.0, 2.0, -PI + 0.1)];
        let e = world.spawn(ParticleSet::from_poses(&poses)).id();
        world.run_system_once(estimate).expect("estimate runs");
        let est = world.get::<PoseEstimate>(e).expect("ParticleSet requires PoseEstimate");
        assert!((est.pose.x - 2.0).abs() < 1e-5 && (est.pose.y - 2.0).abs() < 1e-5, "{est:?}");
        assert!(angle_error(est.pose.yaw, PI) < 1e-4, "mean heading must be π, got {}", est.pose.yaw);
        assert!((est.cov[2][2] - 0.01).abs() < 1e-4, "yaw variance uses wrapped deviations: {est:?}");
        assert!((est.cov[0][0] - 1.0).abs() < 1e-5 && est.cov[1][1].abs() < 1e-6, "{est:?}");
    }

    #[test]
    fn estimate_weights_particles() {
        let mut set = ParticleSet::from_weights(&[3.0, 1.0]);
        set.x = vec![0.0, 4.0];
        let est = estimate_pose(&set).expect("non-empty set");
        assert!((est.pose.x - 1.0).abs() < 1e-5, "0.75·0 + 0.25·4 = 1, got {}", est.pose.x);
        assert!((est.cov[0][0] - 3.0).abs() < 1e-4, "0.75·1 + 0.25·9 = 3, got {}", est.cov[0][0]);
        assert!(estimate_pose(&ParticleSet::default()).is_none(), "empty set has no estimate");
    }
}
