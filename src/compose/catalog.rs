//! The standard registry: every system apfn ships, in dataflow order. A new system (a learned
//! likelihood, a belief projection, an agent) joins by adding one `register` call here.

use crate::act::{BumpShieldParams, Collided, DriveCommand, bump_shield, drive, physics};
use crate::agent::sac::{
    Reward, RewardParams, SacPolicyParams, SacUpdateParams, localization_reward, sac_policy, sac_update,
};
use crate::agent::{
    Action, AvoidParams, GoalnavParams, InfogainParams, TurnParams, avoid_policy, goalnav_policy,
    infogain_policy, random_policy, turn_policy,
};
use crate::belief::{BeliefCrop, BeliefParams, belief_crop};
use crate::compose::registry::{Registry, SystemSpec};
use crate::episode::{Episode, EpisodeStart, KidnapParams, StepError, episode_reset, kidnap, step_metrics};
use crate::params::{NoParams, StepData};
use crate::particles::{
    BeamModelParams, InitParams, LikelihoodFieldParams, LikelihoodStats, ParticleSet, PfNetLikelihoodParams,
    PoseEstimate, RecoveryBeforeUpdateParams, RecoveryParams, ResampleParams, TransitionParams,
    augmented_recovery, estimate, init_particles, mcl_beam_model, mcl_likelihood_field, pfnet_likelihood,
    recovery_before_update, resample, transition,
};
use crate::replay::log_feed;
use crate::sense::{
    DepthParams, DepthStrip, LidarParams, LidarScan, LocalGrid, LocalGridParams, Odometry, OdometryParams,
    ScanMatchingParams, depth, lidar, local_grid, odometry, scan_matching,
};
use crate::stage::ApfnSet::{self, *};
use crate::world::TruePose;

/// `data![A, B]`: the components A and B, as a step's needs or products.
macro_rules! data {
    ($($component:ty),*) => { vec![$(StepData::of::<$component>()),*] };
}

fn spec(
    name: &'static str,
    stage: ApfnSet,
    summary: &'static str,
    needs: Vec<StepData>,
    produces: Vec<StepData>,
) -> SystemSpec {
    SystemSpec { name, stage, summary, needs, produces }
}

/// All systems apfn ships.
pub fn standard_registry() -> Registry {
    let mut r = Registry::default();
    r.register::<NoParams, _, _>(
        spec(
            "episode_reset",
            Episode,
            "Reads EpisodeParams, maps, other robots' poses. Writes Episode, TruePose, physics, EpisodeStart; empties ParticleSet.",
            data![],
            data![Episode, EpisodeStart],
        ),
        episode_reset,
    )
    .register::<KidnapParams, _, _>(
        spec(
            "kidnap",
            Episode,
            "Reads Episode, the map's layers. Writes TruePose, PreviousPose (carried along), physics.",
            data![],
            data![],
        ),
        kidnap,
    )
    .register::<OdometryParams, _, _>(
        spec(
            "odometry",
            Sense,
            "Reads TruePose, PreviousPose. Writes Odometry (noisy), PreviousPose.",
            data![],
            data![Odometry],
        ),
        odometry,
    )
    .register::<LidarParams, _, _>(
        spec("lidar", Sense, "Reads TruePose, the map's RayGrid. Writes LidarScan.", data![], data![LidarScan]),
        lidar,
    )
    .register::<ScanMatchingParams, _, _>(
        spec(
            "scan_matching",
            Sense,
            "Reads LidarScan, Odometry, EpisodeStart. Writes Odometry (heading change aligned with the \
             previous scan, and its error), ScanMemory.",
            data![LidarScan, Odometry],
            data![Odometry],
        ),
        scan_matching,
    )
    .register::<NoParams, _, _>(
        spec(
            "log_feed",
            Sense,
            "Reads LogFeed (recorded readings). Writes Odometry, LidarScan, TruePose (when logged).",
            data![],
            data![Odometry, LidarScan],
        ),
        log_feed,
    )
    .register::<LocalGridParams, _, _>(
        spec(
            "local_grid",
            Sense,
            "Reads LidarScan. Writes LocalGrid (0 occupied, 0.5 unknown, 1 free).",
            data![LidarScan],
            data![LocalGrid],
        ),
        local_grid,
    )
    .register::<DepthParams, _, _>(
        spec("depth", Sense, "Reads TruePose, the map's RayGrid. Writes DepthStrip.", data![], data![DepthStrip]),
        depth,
    )
    .register::<InitParams, _, _>(
        spec(
            "init_particles",
            Particles,
            "Reads NeedsInit, TruePose, the map's layers. Writes ParticleSet (draws marked sets).",
            data![],
            data![ParticleSet],
        ),
        init_particles,
    )
    .register::<TransitionParams, _, _>(
        spec(
            "transition",
            Particles,
            "Reads Odometry. Writes ParticleSet poses.",
            data![ParticleSet, Odometry],
            data![],
        ),
        transition,
    )
    .register::<RecoveryBeforeUpdateParams, _, _>(
        spec(
            "recovery_before_update",
            Particles,
            "Reads the last update's LikelihoodStats, the map's layers. Writes ParticleSet (uniform injections at prior weight, for the next update to weigh).",
            data![ParticleSet],
            data![],
        ),
        recovery_before_update,
    )
    .register::<LikelihoodFieldParams, _, _>(
        spec(
            "mcl_likelihood_field",
            Particles,
            "Reads LidarScan, the map's DistanceField. Writes ParticleSet weights, LikelihoodStats.",
            data![ParticleSet, LidarScan],
            data![LikelihoodStats],
        ),
        mcl_likelihood_field,
    )
    .register::<BeamModelParams, _, _>(
        spec(
            "mcl_beam_model",
            Particles,
            "Reads LidarScan, the map's RayGrid. Writes ParticleSet weights, LikelihoodStats.",
            data![ParticleSet, LidarScan],
            data![LikelihoodStats],
        ),
        mcl_beam_model,
    )
    .register::<PfNetLikelihoodParams, _, _>(
        spec(
            "pfnet_likelihood",
            Particles,
            "Reads LocalGrid, the map's NetworkMap. Writes ParticleSet weights, LikelihoodStats.",
            data![ParticleSet, LocalGrid],
            data![LikelihoodStats],
        ),
        pfnet_likelihood,
    )
    .register::<RecoveryParams, _, _>(
        spec(
            "augmented_recovery",
            Particles,
            "Reads LikelihoodStats, LidarScan, the map's layers. Writes ParticleSet (uniform injections).",
            data![ParticleSet, LidarScan, LikelihoodStats],
            data![],
        ),
        augmented_recovery,
    )
    .register::<ResampleParams, _, _>(
        spec("resample", Particles, "Reads ParticleSet weights. Writes ParticleSet.", data![ParticleSet], data![]),
        resample,
    )
    .register::<NoParams, _, _>(
        spec(
            "estimate",
            Particles,
            "Reads ParticleSet. Writes PoseEstimate.",
            data![ParticleSet],
            data![PoseEstimate],
        ),
        estimate,
    )
    .register::<BeliefParams, _, _>(
        spec(
            "belief_crop",
            Belief,
            "Reads ParticleSet, PoseEstimate, the map's NetworkMap. Writes BeliefCrop.",
            data![ParticleSet, PoseEstimate],
            data![BeliefCrop],
        ),
        belief_crop,
    )
    .register::<NoParams, _, _>(
        spec(
            "step_metrics",
            Evaluate,
            "Reads TruePose, PoseEstimate, Episode. Writes StepError, EpisodeLog, CompletedEpisodes.",
            data![Episode, PoseEstimate],
            data![StepError],
        ),
        step_metrics,
    )
    .register::<RewardParams, _, _>(
        spec(
            "localization_reward",
            Evaluate,
            "Reads PoseEstimate, TruePose, Collided, EpisodeStart. Writes Reward (of the last action).",
            data![EpisodeStart, PoseEstimate],
            data![Reward],
        ),
        localization_reward,
    )
    .register::<NoParams, _, _>(
        spec("random_policy", Agent, "Reads ScenarioRng. Writes Action.", data![], data![Action]),
        random_policy,
    )
    .register::<TurnParams, _, _>(
        spec("turn_policy", Agent, "Reads TurnParams. Writes Action.", data![], data![Action]),
        turn_policy,
    )
    .register::<AvoidParams, _, _>(
        spec("avoid_policy", Agent, "Reads DepthStrip, AvoidParams, RobotParams. Writes Action.", data![DepthStrip], data![Action]),
        avoid_policy,
    )
    .register::<GoalnavParams, _, _>(
        spec("goalnav_policy", Agent, "Reads TruePose (or PoseEstimate), EpisodeStart, the map's TraversableMap, ScenarioRng. Writes GoalPlan, Action.", data![], data![Action]),
        goalnav_policy,
    )
    .register::<InfogainParams, _, _>(
        spec("infogain_policy", Agent, "Reads ParticleSet, the map's RayGrid, DistanceField and TraversableMap, the filter's LidarParams, LikelihoodFieldParams and TransitionParams, ScenarioRng. Writes Action.", data![ParticleSet], data![Action]),
        infogain_policy,
    )
    .register::<SacPolicyParams, _, _>(
        spec(
            "sac_policy",
            Agent,
            "Reads BeliefCrop, LocalGrid, Collided, Episode, Reward, the learning agent if any, ScenarioRng (with `sample`). Writes Action, the agent's replay buffer.",
            data![BeliefCrop, LocalGrid, Reward],
            data![Action],
        ),
        sac_policy,
    )
    .register::<SacUpdateParams, _, _>(
        spec("sac_update", Agent, "Reads the learning agent's replay buffer. Writes its networks.", data![], data![]),
        sac_update,
    )
    .register::<NoParams, _, _>(
        spec("drive", Act, "Reads Action, RobotParams. Writes DriveCommand.", data![Action], data![DriveCommand]),
        drive,
    )
    .register::<BumpShieldParams, _, _>(
        spec(
            "bump_shield",
            Act,
            "Reads LidarScan, DriveCommand, RobotParams, PhysicsParams. Writes DriveCommand (forward speed cut so the step's sweep stays clear of the scan).",
            data![LidarScan, DriveCommand],
            data![DriveCommand],
        ),
        bump_shield,
    )
    .register::<NoParams, _, _>(
        spec(
            "physics",
            Act,
            "Reads DriveCommand, the scene's PhysicsParams. Writes TruePose, Collided, MapPhysics.",
            data![DriveCommand],
            data![TruePose, Collided],
        ),
        physics,
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::StepParams;

    #[test]
    fn standard_registry_declarations_match_what_each_system_touches() {
        for entry in standard_registry().entries() {
            entry.check_declarations(&[]).unwrap_or_else(|e| panic!("{e}"));
        }
        let goalnav = GoalnavParams { use_estimate: true, ..GoalnavParams::default() };
        let entry = standard_registry().get("goalnav_policy").map(|e| e.check_declarations(&goalnav.needs()));
        assert_eq!(entry, Some(Ok(())), "goalnav reads the estimate it asks for");
    }

    #[test]
    fn check_declarations_catches_a_false_claim() {
        let mut registry = Registry::default();
        let claim = spec("claims", Particles, "", data![PoseEstimate], data![ParticleSet]);
        registry.register::<NoParams, _, _>(claim, |_: bevy::prelude::Query<&ParticleSet>| {});
        let err = registry.entries()[0].check_declarations(&[]).expect_err("false claims");
        assert!(
            err.contains("needs PoseEstimate but never reads it")
                && err.contains("produces ParticleSet but never writes it"),
            "{err}"
        );
    }
}
