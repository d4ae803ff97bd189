//! The agent's reward (paper, eq. 6): minus the squared pose error of the filter's estimate after
//! this step's update, r = −(Δx² + Δy² + 0.36 Δθ²) in m² and rad², and −0.1 when the robot
//! touched anything while executing the action. Beyond the paper, `form: distance` pays the
//! square root of that loss instead: metres, the scale of the tables' mean position error.

use crate::act::Collided;
use crate::episode::EpisodeStart;
use crate::params::{StepParams, expect_param};
use crate::particles::PoseEstimate;
use crate::world::{TruePose, angle_error};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RewardParams {
    /// Weight of the squared heading error, per rad² (paper: 0.36).
    pub heading_weight: f32,
    /// Subtracted when the robot touched anything during the step (paper: 0.1).
    pub collision_penalty: f32,
    /// Caps the pose loss Δx² + Δy² + w·Δθ² at this value (m²) before the penalty; `None`, the
    /// paper's unbounded loss. Beyond the paper: a lost filter's loss is tens of m² per step, so
    /// a few such episodes dominate every critic batch; a cap keeps the critics' targets in range.
    pub max_loss: Option<f32>,
    /// What the (capped) loss pays: itself (the paper) or its square root.
    pub form: RewardForm,
}

/// How the pose loss L = Δx² + Δy² + w·Δθ² becomes a reward.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum RewardForm {
    /// r = −L (paper, eq. 6): a step 3 m off costs 100 times one 0.3 m off, so the first steps
    /// of a global localization, which no motion shortens much, outweigh the convergence after.
    #[default]
    Squared,
    /// r = −√L, metres: each step weighs its error as the tables' mean position error does, and
    /// a lost filter costs metres, not tens of m², so no cap is needed to keep targets in range.
    Distance,
}

impl Default for RewardParams {
    fn default() -> Self {
        Self { heading_weight: 0.36, collision_penalty: 0.1, max_loss: None, form: RewardForm::Squared }
    }
}

impl StepParams for RewardParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.heading_weight >= 0.0, "heading_weight", "≥ 0")?;
        expect_param(self.collision_penalty >= 0.0, "collision_penalty", "≥ 0 (it is subtracted)")?;
        expect_param(self.max_loss.is_none_or(|m| m > 0.0), "max_loss", "a cap > 0 m², or None")
    }
}

/// The reward of the action the robot took in the previous step; `None` in the first step of
/// an episode, which follows no action of its own.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Reward(pub Option<f32>);

/// r for an estimate against the truth.
pub fn reward(estimate: &PoseEstimate, truth: &TruePose, collided: bool, params: &RewardParams) -> f32 {
    let (e, t) = (estimate.pose, truth.0);
    let (dx, dy, dyaw) = (e.x - t.x, e.y - t.y, angle_error(e.yaw, t.yaw));
    let penalty = if collided { params.collision_penalty } else { 0.0 };
    let loss = dx * dx + dy * dy + params.heading_weight * dyaw * dyaw;
    let capped = params.max_loss.map_or(loss, |cap| loss.min(cap));
    let cost = match params.form {
        RewardForm::Squared => capped,
        RewardForm::Distance => capped.sqrt(),
    };
    -cost - penalty
}

/// Reads PoseEstimate, TruePose, Collided, EpisodeStart, RewardParams. Writes Reward.
pub fn localization_reward(
    params: Res<RewardParams>,
    mut robots: Query<(&PoseEstimate, &TruePose, &Collided, Has<EpisodeStart>, &mut Reward)>,
) {
    for (estimate, truth, collided, starting, mut r) in &mut robots {
        r.0 = (!starting).then(|| reward(estimate, truth, collided.0, &params));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Pose2;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn reward_is_minus_the_weighted_squared_error_and_the_bump() {
        let truth = TruePose(Pose2::new(1.0, 2.0, 0.1));
        let estimate = PoseEstimate { pose: Pose2::new(1.3, 1.6, 0.6), ..Default::default() };
        let want = -(0.09 + 0.16 + 0.36 * 0.25);
        let params = RewardParams::default();
        assert!((reward(&estimate, &truth, false, &params) - want).abs() < 1e-5);
        assert!((reward(&estimate, &truth, true, &params) - (want - 0.1)).abs() < 1e-5);
        let wrapped = PoseEstimate {
            pose: Pose2::new(1.0, 2.0, 0.1 + 2.0 * std::f32::consts::PI),
            ..Default::default()
        };
        assert!(reward(&wrapped, &truth, false, &params).abs() < 1e-5, "headings wrap");
    }

    #[test]
    fn a_capped_reward_stops_at_the_cap_and_still_pays_the_bump() {
        let truth = TruePose(Pose2::new(0.0, 0.0, 0.0));
        let lost = PoseEstimate { pose: Pose2::new(3.0, 4.0, 0.0), ..Default::default() };
        let near = PoseEstimate { pose: Pose2::new(0.3, 0.4, 0.0), ..Default::default() };
        let capped = RewardParams { max_loss: Some(2.0), ..Default::default() };
        assert!((reward(&lost, &truth, false, &RewardParams::default()) + 25.0).abs() < 1e-4);
        assert!((reward(&lost, &truth, false, &capped) + 2.0).abs() < 1e-6, "25 m² capped at 2");
        assert!((reward(&lost, &truth, true, &capped) + 2.1).abs() < 1e-6, "the bump comes on top");
        assert!((reward(&near, &truth, false, &capped) + 0.25).abs() < 1e-6, "below the cap: unchanged");
        assert!(RewardParams { max_loss: Some(0.0), ..Default::default() }.check().is_err());
    }

    #[test]
    fn the_distance_form_pays_the_root_of_the_loss() {
        let truth = TruePose(Pose2::new(0.0, 0.0, 0.0));
        let estimate = PoseEstimate { pose: Pose2::new(3.0, 4.0, 1.0), ..Default::default() };
        let distance = RewardParams { form: RewardForm::Distance, ..Default::default() };
        let root = (25.0f32 + 0.36).sqrt();
        assert!((reward(&estimate, &truth, false, &distance) + root).abs() < 1e-5);
        assert!((reward(&estimate, &truth, true, &distance) + root + 0.1).abs() < 1e-5, "the bump stays");
        let capped = RewardParams { max_loss: Some(4.0), ..distance };
        assert!((reward(&estimate, &truth, false, &capped) + 2.0).abs() < 1e-6, "the cap applies first");
    }

    #[test]
    fn the_first_step_of_an_episode_has_no_reward() {
        let mut world = World::new();
        world.insert_resource(RewardParams::default());
        let pose = Pose2::new(0.0, 0.0, 0.0);
        let estimate = PoseEstimate { pose, ..Default::default() };
        let parts = (estimate, TruePose(pose), Collided(true), Reward(Some(-5.0)));
        let (fresh, going) = (world.spawn((parts, EpisodeStart)).id(), world.spawn(parts).id());
        world.run_system_once(localization_reward).unwrap();
        assert_eq!(world.get::<Reward>(fresh), Some(&Reward(None)));
        assert_eq!(world.get::<Reward>(going), Some(&Reward(Some(-0.1))));
    }
}
