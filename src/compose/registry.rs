//! The system registry: every system apfn can schedule, under a stable name, with its stage,
//! typed parameters (defaults = the paper's values) and the components it needs and produces.

use crate::params::{StepData, StepParams, pretty_ron};
use crate::stage::ApfnSet;
use bevy::ecs::query::Access;
use bevy::ecs::schedule::{ScheduleLabel, SystemSet};
use bevy::prelude::*;
use std::marker::PhantomData;

/// A system with its parameters decoded, ready to be added to an `App`.
pub trait ConfiguredSystem: Send + Sync {
    /// Inserts the parameters as a resource and adds the system to `Update` in `slot` and `stage`.
    fn install(&self, app: &mut App, slot: StepSlot, stage: ApfnSet);
    /// The parameters as pretty RON, for listings.
    fn params_ron(&self) -> String;
    /// [`StepParams::optional_defaults`] of the parameter type, for listings.
    fn optional_ron(&self) -> Vec<(&'static str, String)>;
    /// [`StepParams::needs`]: what the parameter values add to the system's registered needs.
    fn param_needs(&self) -> Vec<StepData>;
    /// A copy, so one validated pipeline can configure many worlds.
    fn boxed_clone(&self) -> Box<dyn ConfiguredSystem>;
}

/// The position of a step in its schedule file; slots run in file order.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StepSlot(pub usize);

type Parser = Box<
    dyn Fn(&mut dyn erased_serde::Deserializer<'_>) -> Result<Box<dyn ConfiguredSystem>, erased_serde::Error>
        + Send
        + Sync,
>;

/// One registry entry.
pub struct RegisteredSystem {
    pub name: &'static str,
    pub stage: ApfnSet,
    /// "Reads … Writes …", as the system's first doc line.
    pub summary: &'static str,
    /// Components some earlier step of the schedule must produce, whatever the parameters.
    pub needs: Vec<StepData>,
    /// Components this system writes for later steps.
    pub produces: Vec<StepData>,
    parse: Parser,
    defaults: Box<dyn Fn() -> Box<dyn ConfiguredSystem> + Send + Sync>,
    access: Box<dyn Fn(&mut World) -> SystemAccess + Send + Sync>,
}

/// What a system touches, as bevy's scheduler sees it.
struct SystemAccess {
    access: Access,
    /// The system queues commands, so it may insert components it never borrows.
    deferred: bool,
}

impl RegisteredSystem {
    /// Decodes this system's parameters straight from the schedule file's deserializer, so a
    /// bad field is reported at its own line and column.
    pub fn parse_params(
        &self,
        de: &mut dyn erased_serde::Deserializer<'_>,
    ) -> Result<Box<dyn ConfiguredSystem>, erased_serde::Error> {
        (self.parse)(de)
    }

    pub fn with_defaults(&self) -> Box<dyn ConfiguredSystem> {
        (self.defaults)()
    }

    /// Checks the declared needs (with `param_needs`) and products against the system's real ECS
    /// access: each need must be read (or filtered on), each product written (or, for a system
    /// that queues commands, possibly inserted). `Err` lists every claim the system does not back.
    pub fn check_declarations(&self, param_needs: &[StepData]) -> Result<(), String> {
        let mut world = World::new();
        let SystemAccess { access, deferred } = (self.access)(&mut world);
        let mut wrong = Vec::new();
        for need in self.needs.iter().chain(param_needs) {
            let id = need.component_id(&mut world);
            if !access.has_read(id) && !access.has_archetypal(id) {
                wrong.push(format!("needs {} but never reads it", need.name));
            }
        }
        for product in &self.produces {
            if !access.has_write(product.component_id(&mut world)) && !deferred {
                wrong.push(format!("produces {} but never writes it", product.name));
            }
        }
        if wrong.is_empty() { Ok(()) } else { Err(format!("`{}` {}", self.name, wrong.join("; "))) }
    }
}

struct WithParams<P, S, M> {
    params: P,
    system: S,
    /// The system's marker type, which bevy needs to turn `S` into a system.
    marker: PhantomData<fn() -> M>,
}

impl<P, S, M> ConfiguredSystem for WithParams<P, S, M>
where
    P: StepParams,
    S: IntoSystem<(), (), M> + Copy + Send + Sync + 'static,
    M: 'static,
{
    fn install(&self, app: &mut App, slot: StepSlot, stage: ApfnSet) {
        app.insert_resource(self.params.clone());
        app.add_systems(Update, self.system.in_set(slot).in_set(stage));
    }

    fn params_ron(&self) -> String {
        pretty_ron(&self.params)
    }

    fn optional_ron(&self) -> Vec<(&'static str, String)> {
        P::optional_defaults()
    }

    fn param_needs(&self) -> Vec<StepData> {
        self.params.needs()
    }

    fn boxed_clone(&self) -> Box<dyn ConfiguredSystem> {
        Box::new(WithParams { params: self.params.clone(), system: self.system, marker: PhantomData })
    }
}

/// Every system apfn can schedule. Adding a system is adding one `register` call.
#[derive(Default)]
pub struct Registry {
    entries: Vec<RegisteredSystem>,
}

/// How a system is described in the registry, apart from its function and parameter type.
pub struct SystemSpec {
    pub name: &'static str,
    pub stage: ApfnSet,
    pub summary: &'static str,
    pub needs: Vec<StepData>,
    pub produces: Vec<StepData>,
}

impl Registry {
    /// Registers `system` whose parameters are the resource `P` (use `NoParams` for none).
    pub fn register<P, S, M>(&mut self, spec: SystemSpec, system: S) -> &mut Self
    where
        P: StepParams,
        S: IntoSystem<(), (), M> + Copy + Send + Sync + 'static,
        M: 'static,
    {
        assert!(self.get(spec.name).is_none(), "system `{}` registered twice", spec.name);
        let parse: Parser = Box::new(move |de| {
            let params: P = erased_serde::deserialize(de)?;
            params.check().map_err(<erased_serde::Error as serde::de::Error>::custom)?;
            Ok(Box::new(WithParams { params, system, marker: PhantomData }) as Box<dyn ConfiguredSystem>)
        });
        let defaults = Box::new(move || {
            Box::new(WithParams { params: P::default(), system, marker: PhantomData }) as Box<_>
        });
        let access = Box::new(move |world: &mut World| {
            let mut system = IntoSystem::into_system(system);
            let access = system.initialize(world).combined_access().clone();
            SystemAccess { access, deferred: system.has_deferred() }
        });
        self.entries.push(RegisteredSystem {
            name: spec.name,
            stage: spec.stage,
            summary: spec.summary,
            needs: spec.needs,
            produces: spec.produces,
            parse,
            defaults,
            access,
        });
        self
    }

    pub fn get(&self, name: &str) -> Option<&RegisteredSystem> {
        self.entries.iter().find(|e| e.name == name)
    }

    pub fn entries(&self) -> &[RegisteredSystem] {
        &self.entries
    }

    /// Known names sorted, for error messages.
    pub fn names(&self) -> Vec<&'static str> {
        let mut names: Vec<_> = self.entries.iter().map(|e| e.name).collect();
        names.sort_unstable();
        names
    }

    /// The registered name closest to `unknown` (edit distance), if any is plausibly meant.
    pub fn nearest(&self, unknown: &str) -> Option<&'static str> {
        self.entries
            .iter()
            .map(|e| (edit_distance(unknown, e.name), e.name))
            .filter(|(d, name)| *d <= name.len().max(unknown.len()) / 2)
            .min()
            .map(|(_, name)| name)
    }
}

/// Adds the step-slot chain for `n` steps to `schedule`, so steps run in file order.
pub fn chain_slots(app: &mut App, schedule: impl ScheduleLabel + Clone, n: usize) {
    for i in 1..n {
        app.configure_sets(schedule.clone(), StepSlot(i).after(StepSlot(i - 1)));
    }
}

/// Levenshtein distance, for "did you mean" suggestions.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let next = (row[j + 1] + 1).min(row[j] + 1).min(diagonal + usize::from(ca != cb));
            diagonal = row[j + 1];
            row[j + 1] = next;
        }
    }
    row[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::NoParams;

    #[test]
    fn nearest_suggests_a_close_name_only() {
        let mut registry = Registry::default();
        let spec =
            |name| SystemSpec { name, stage: ApfnSet::Sense, summary: "", needs: vec![], produces: vec![] };
        registry.register::<NoParams, _, _>(spec("lidar"), || {});
        registry.register::<NoParams, _, _>(spec("odometry"), || {});
        assert_eq!(registry.nearest("lidr"), Some("lidar"));
        assert_eq!(registry.nearest("odometri"), Some("odometry"));
        assert_eq!(registry.nearest("completely_else"), None);
    }
}
