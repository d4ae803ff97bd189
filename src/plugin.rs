//! `ApfnPlugin`: adds apfn's resources, stages and a validated pipeline to any bevy `App`.

use crate::act::PhysicsParams;
use crate::compose::Pipeline;
use crate::episode::CompletedEpisodes;
use bevy::prelude::*;

pub use crate::stage::ApfnSet;

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
/// agent step. Returns the robots in spawn order. A policy checkpoint whose inputs the schedule
/// does not produce is an error (see [`check_policy_inputs`]).
pub fn headless_app(
    scene: &crate::compose::LoadedScene,
    pipeline: Pipeline,
) -> Result<(App, Vec<Entity>), crate::compose::ComposeError> {
    check_policy_inputs(&pipeline)?;
    let mut app = App::new();
    app.add_plugins(ApfnPlugin { pipeline });
    let robots = crate::compose::spawn_scene(app.world_mut(), scene)?;
    Ok((app, robots))
}

/// `Err` naming the schedule and its `sac_policy` step when the policy checkpoint that step loads
/// reads crops, a grid or a depth strip the schedule's steps do not produce, so that a run fails
/// before its first step instead of writing results for robots that never moved.
pub fn check_policy_inputs(pipeline: &Pipeline) -> Result<(), crate::compose::ComposeError> {
    let Some(index) = pipeline.names().iter().position(|&name| name == "sac_policy") else {
        return Ok(());
    };
    let mut app = App::new();
    pipeline.install(&mut app);
    crate::agent::sac::check_policy_inputs(app.world()).map_err(|message| {
        crate::compose::ComposeError::Step {
            path: pipeline.source.clone(),
            index: index + 1,
            name: "sac_policy".into(),
            message,
        }
    })
}
