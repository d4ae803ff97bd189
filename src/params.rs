//! The contract of a schedulable system's parameters, below every stage: each system's params
//! struct implements [`StepParams`], and `compose` decodes schedule files into them.

use bevy::ecs::component::ComponentId;
use bevy::prelude::{Component, Resource, World};
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::any::TypeId;

/// The parameters of a schedulable system: a resource decoded from the schedule file, then
/// checked for what its type cannot say (ranges, orderings), so that a bad value fails when the
/// schedule loads, naming the file and step, instead of mid-run.
pub trait StepParams: Resource + Serialize + DeserializeOwned + Default + Clone {
    /// `Err("field: expected …")` when a value is out of range.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }

    /// What these parameter values make the system read beyond its registered needs, for some
    /// earlier step to produce: e.g. goalnav's `PoseEstimate` when it steers by the estimate.
    fn needs(&self) -> Vec<StepData> {
        Vec::new()
    }

    /// Optional groups of parameters that are off by default (`None`), each with the fields and
    /// defaults it takes when switched on (`Some(())`), as pretty RON: what a listing shows
    /// beyond `field: None`.
    fn optional_defaults() -> Vec<(&'static str, String)> {
        Vec::new()
    }
}

/// A component one step of a schedule writes for later steps to read: named for messages, typed
/// so that the registry can check each claim against the system's real ECS access.
#[derive(Clone, Copy, Debug)]
pub struct StepData {
    /// The type's name without its module path ("ParticleSet").
    pub name: &'static str,
    type_id: TypeId,
    register: fn(&mut World) -> ComponentId,
}

impl StepData {
    pub fn of<T: Component>() -> StepData {
        let path = std::any::type_name::<T>();
        StepData {
            name: path.rsplit("::").next().unwrap_or(path),
            type_id: TypeId::of::<T>(),
            register: World::register_component::<T>,
        }
    }

    /// The component's id in `world` (registered if it was not yet).
    pub fn component_id(&self, world: &mut World) -> ComponentId {
        (self.register)(world)
    }
}

impl PartialEq for StepData {
    fn eq(&self, other: &Self) -> bool {
        self.type_id == other.type_id
    }
}

/// `value` as the pretty RON listings print, with struct names.
pub fn pretty_ron(value: &impl Serialize) -> String {
    ron::ser::to_string_pretty(value, ron::ser::PrettyConfig::default().struct_names(true))
        .unwrap_or_else(|e| format!("<unprintable: {e}>"))
}

/// `Err("{field}: expected {expected}")` unless `ok`; the building block of [`StepParams::check`].
pub fn expect_param(ok: bool, field: &str, expected: &str) -> Result<(), String> {
    if ok { Ok(()) } else { Err(format!("{field}: expected {expected}")) }
}

/// Parameters of systems that take none (`("lidar", ())` in a schedule file).
#[derive(Resource, serde::Deserialize, Serialize, Clone, Debug, Default, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

impl StepParams for NoParams {}
