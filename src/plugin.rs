//! `ApfnPlugin`: adds apfn's resources, stages and a validated pipeline to any bevy `App`.

use crate::act::PhysicsParams;
use crate::compose::Pipeline;
use crate::episode::CompletedEpisodes;
use bevy::prelude::*;

/// The stages of one agent step, in order. Every registered system runs in one of them, so a
/// user's own system can be placed with `.in_set(ApfnSet::Agent)` or `.after(ApfnSet::Particles)`.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ApfnSet {
    /// Episode bookkeeping at the start of a step: resets, new start poses.
    Episode,
    /// Odometry and sensors read the world.
    Sense,
    /// The filter: init, transition, likelihood, resampling, estimate.
    Particles,
    /// Belief projection for the agent.
    Belief,
    /// Per-step errors and rewards, on the estimate the agent is about to act on.
    Evaluate,
    /// Policies write the action.
    Agent,
    /// Drive and physics move the robots.
    Act,
}

impl ApfnSet {
    pub const ALL: [ApfnSet; 7] = [
        ApfnSet::Episode,
        ApfnSet::Sense,
        ApfnSet::Particles,
        ApfnSet::Belief,
        ApfnSet::Evaluate,
        ApfnSet::Agent,
        ApfnSet::Act,
    ];
}

/// Adds the stages (chained in `ApfnSet` order), default physics timing (a scene's replaces it),
/// the list of finished episodes and the pipeline's systems to the `Update` schedule: one `app.update()` is one agent step.
pub struct ApfnPlugin {
    pub pipeline: Pipeline,
}

impl Plugin for ApfnPlugin {
    fn build(&self, app: &mut App) {
        use ApfnSet::*;
        app.init_resource::<CompletedEpisodes>()
            .init_resource::<PhysicsParams>()
            .configure_sets(Update, (Episode, Sense, Particles, Belief, Evaluate, Agent, Act).chain());
        self.pipeline.install(app);
    }
}

/// A headless `App` running `pipeline` on the scene's maps and robots: one `update()` is one
/// agent step. Returns the robots in spawn order.
pub fn headless_app(
    scene: &crate::compose::LoadedScene,
    pipeline: Pipeline,
) -> Result<(App, Vec<Entity>), crate::compose::ComposeError> {
    let mut app = App::new();
    app.add_plugins(ApfnPlugin { pipeline });
    let robots = crate::compose::spawn_scene(app.world_mut(), scene)?;
    Ok((app, robots))
}
