//! The standard registry: every system apfn ships, in dataflow order. A new system (a learned
//! likelihood, a belief projection, an agent) joins by adding one `register` call here.

use crate::act::{drive, physics};
use crate::agent::sac::{
    RewardParams, SacPolicyParams, SacUpdateParams, localization_reward, sac_policy, sac_update,
};
use crate::agent::{
    AvoidParams, GoalnavParams, InfogainParams, TurnParams, avoid_policy, goalnav_policy, infogain_policy,
    random_policy, turn_policy,
};
use crate::belief::{BeliefParams, belief_crop};
use crate::compose::registry::{NoParams, Registry, SystemSpec};
use crate::episode::{KidnapParams, episode_reset, kidnap, step_metrics};
use crate::particles::{
    BeamModelParams, InitParams, LikelihoodFieldParams, PfNetLikelihoodParams, RecoveryParams,
    ResampleParams, TransitionParams, augmented_recovery, estimate, init_particles, mcl_beam_model,
    mcl_likelihood_field, pfnet_likelihood, resample, transition,
};
use crate::plugin::ApfnSet::{self, *};
use crate::sense::{
    DepthParams, LidarParams, LocalGridParams, OdometryParams, depth, lidar, local_grid, odometry,
};

fn spec(
    name: &'static str,
    stage: ApfnSet,
    summary: &'static str,
    needs: &'static [&'static str],
    produces: &'static [&'static str],
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
            &[],
            &["EpisodeStart"],
        ),
        episode_reset,
    )
    .register::<KidnapParams, _, _>(
        spec(
            "kidnap",
            Episode,
            "Reads Episode, the map's layers. Writes TruePose, PreviousPose (carried along), physics.",
            &[],
            &[],
        ),
        kidnap,
    )
    .register::<OdometryParams, _, _>(
        spec(
            "odometry",
            Sense,
            "Reads TruePose, PreviousPose. Writes Odometry (noisy), PreviousPose.",
            &[],
            &["Odometry"],
        ),
        odometry,
    )
    .register::<LidarParams, _, _>(
        spec("lidar", Sense, "Reads TruePose, the map's RayGrid. Writes LidarScan.", &[], &["LidarScan"]),
        lidar,
    )
    .register::<LocalGridParams, _, _>(
        spec(
            "local_grid",
            Sense,
            "Reads LidarScan. Writes LocalGrid (0 occupied, 0.5 unknown, 1 free).",
            &["LidarScan"],
            &["LocalGrid"],
        ),
        local_grid,
    )
    .register::<DepthParams, _, _>(
        spec("depth", Sense, "Reads TruePose, the map's RayGrid. Writes DepthStrip.", &[], &["DepthStrip"]),
        depth,
    )
    .register::<InitParams, _, _>(
        spec(
            "init_particles",
            Particles,
            "Reads NeedsInit, TruePose, the map's layers. Writes ParticleSet (draws marked sets).",
            &[],
            &["ParticleSet"],
        ),
        init_particles,
    )
    .register::<TransitionParams, _, _>(
        spec(
            "transition",
            Particles,
            "Reads Odometry. Writes ParticleSet poses.",
            &["ParticleSet", "Odometry"],
            &[],
        ),
        transition,
    )
    .register::<LikelihoodFieldParams, _, _>(
        spec(
            "mcl_likelihood_field",
            Particles,
            "Reads LidarScan, the map's DistanceField. Writes ParticleSet weights, LikelihoodStats.",
            &["ParticleSet", "LidarScan"],
            &["LikelihoodStats"],
        ),
        mcl_likelihood_field,
    )
    .register::<BeamModelParams, _, _>(
        spec(
            "mcl_beam_model",
            Particles,
            "Reads LidarScan, the map's RayGrid. Writes ParticleSet weights, LikelihoodStats.",
            &["ParticleSet", "LidarScan"],
            &["LikelihoodStats"],
        ),
        mcl_beam_model,
    )
    .register::<PfNetLikelihoodParams, _, _>(
        spec(
            "pfnet_likelihood",
            Particles,
            "Reads LocalGrid, the map's NetworkMap. Writes ParticleSet weights, LikelihoodStats.",
            &["ParticleSet", "LocalGrid"],
            &["LikelihoodStats"],
        ),
        pfnet_likelihood,
    )
    .register::<RecoveryParams, _, _>(
        spec(
            "augmented_recovery",
            Particles,
            "Reads LikelihoodStats, LidarScan, the map's layers. Writes ParticleSet (uniform injections).",
            &["ParticleSet", "LidarScan", "LikelihoodStats"],
            &[],
        ),
        augmented_recovery,
    )
    .register::<ResampleParams, _, _>(
        spec("resample", Particles, "Reads ParticleSet weights. Writes ParticleSet.", &["ParticleSet"], &[]),
        resample,
    )
    .register::<NoParams, _, _>(
        spec(
            "estimate",
            Particles,
            "Reads ParticleSet. Writes PoseEstimate.",
            &["ParticleSet"],
            &["PoseEstimate"],
        ),
        estimate,
    )
    .register::<BeliefParams, _, _>(
        spec(
            "belief_crop",
            Belief,
            "Reads ParticleSet, PoseEstimate, the map's NetworkMap. Writes BeliefCrop.",
            &["ParticleSet", "PoseEstimate"],
            &["BeliefCrop"],
        ),
        belief_crop,
    )
    .register::<NoParams, _, _>(
        spec(
            "step_metrics",
            Evaluate,
            "Reads TruePose, PoseEstimate, Episode. Writes StepError, EpisodeLog, CompletedEpisodes.",
            &["EpisodeStart", "PoseEstimate"],
            &["StepError"],
        ),
        step_metrics,
    )
    .register::<RewardParams, _, _>(
        spec(
            "localization_reward",
            Evaluate,
            "Reads PoseEstimate, TruePose, Collided, EpisodeStart. Writes Reward (of the last action).",
            &["EpisodeStart", "PoseEstimate"],
            &["Reward"],
        ),
        localization_reward,
    )
    .register::<NoParams, _, _>(
        spec("random_policy", Agent, "Reads ScenarioRng. Writes Action.", &[], &["Action"]),
        random_policy,
    )
    .register::<TurnParams, _, _>(
        spec("turn_policy", Agent, "Reads TurnParams. Writes Action.", &[], &["Action"]),
        turn_policy,
    )
    .register::<AvoidParams, _, _>(
        spec("avoid_policy", Agent, "Reads DepthStrip, AvoidParams, RobotParams. Writes Action.", &["DepthStrip"], &["Action"]),
        avoid_policy,
    )
    .register::<GoalnavParams, _, _>(
        spec("goalnav_policy", Agent, "Reads TruePose (or PoseEstimate), EpisodeStart, the map's TraversableMap, ScenarioRng. Writes GoalPlan, Action.", &[], &["Action"]),
        goalnav_policy,
    )
    .register::<InfogainParams, _, _>(
        spec("infogain_policy", Agent, "Reads ParticleSet, the map's RayGrid, DistanceField and TraversableMap, the filter's LidarParams, LikelihoodFieldParams and TransitionParams, ScenarioRng. Writes Action.", &["ParticleSet"], &["Action"]),
        infogain_policy,
    )
    .register::<SacPolicyParams, _, _>(
        spec(
            "sac_policy",
            Agent,
            "Reads BeliefCrop, LocalGrid, Collided, Episode, Reward, the learning agent if any. Writes Action, the agent's replay buffer.",
            &["BeliefCrop", "LocalGrid", "Reward"],
            &["Action"],
        ),
        sac_policy,
    )
    .register::<SacUpdateParams, _, _>(
        spec("sac_update", Agent, "Reads the learning agent's replay buffer. Writes its networks.", &[], &[]),
        sac_update,
    )
    .register::<NoParams, _, _>(
        spec("drive", Act, "Reads Action, RobotParams. Writes DriveCommand.", &["Action"], &["DriveCommand"]),
        drive,
    )
    .register::<NoParams, _, _>(
        spec(
            "physics",
            Act,
            "Reads DriveCommand, the scene's PhysicsParams. Writes TruePose, Collided, MapPhysics.",
            &["DriveCommand"],
            &["TruePose", "Collided"],
        ),
        physics,
    );
    r
}
