//! The system registry: every system apfn can schedule, under a stable name, with its stage,
//! typed parameters (defaults = the paper's values) and the components it needs and produces.

use crate::plugin::ApfnSet;
use bevy::ecs::schedule::{IntoScheduleConfigs, ScheduleLabel, SystemSet};
use bevy::ecs::system::ScheduleSystem;
use bevy::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::marker::PhantomData;

/// A system with its parameters decoded, ready to be added to an `App`.
pub trait ConfiguredSystem: Send + Sync {
    /// Inserts the parameters as a resource and adds the system to `Update` in `slot` and `stage`.
    fn install(&self, app: &mut App, slot: StepSlot, stage: ApfnSet);
    /// The parameters as pretty RON, for listings.
    fn params_ron(&self) -> String;
    /// [`StepParams::optional_defaults`] of the parameter type, for listings.
    fn optional_ron(&self) -> Vec<(&'static str, String)>;
    /// A copy, so one validated pipeline can configure many worlds.
    fn boxed_clone(&self) -> Box<dyn ConfiguredSystem>;
}

/// The position of a step in its schedule file; slots run in file order.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StepSlot(pub usize);

/// The parameters of a schedulable system: a resource decoded from the schedule file, then
/// checked for what its type cannot say (ranges, orderings), so that a bad value fails when the
/// schedule loads, naming the file and step, instead of mid-run.
pub trait StepParams: Resource + Serialize + DeserializeOwned + Default + Clone {
    /// `Err("field: expected …")` when a value is out of range.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }

    /// Optional groups of parameters that are off by default (`None`), each with the fields and
    /// defaults it takes when switched on (`Some(())`), as pretty RON: what a listing shows
    /// beyond `field: None`.
    fn optional_defaults() -> Vec<(&'static str, String)> {
        Vec::new()
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
    /// Components or resources some earlier step of the schedule must produce.
    pub needs: &'static [&'static str],
    /// Components or resources this system writes for later steps.
    pub produces: &'static [&'static str],
    parse: Parser,
    defaults: Box<dyn Fn() -> Box<dyn ConfiguredSystem> + Send + Sync>,
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
    S: IntoScheduleConfigs<ScheduleSystem, M> + Copy + Send + Sync + 'static,
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
    pub needs: &'static [&'static str],
    pub produces: &'static [&'static str],
}

impl Registry {
    /// Registers `system` whose parameters are the resource `P` (use `NoParams` for none).
    pub fn register<P, S, M>(&mut self, spec: SystemSpec, system: S) -> &mut Self
    where
        P: StepParams,
        S: IntoScheduleConfigs<ScheduleSystem, M> + Copy + Send + Sync + 'static,
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
        self.entries.push(RegisteredSystem {
            name: spec.name,
            stage: spec.stage,
            summary: spec.summary,
            needs: spec.needs,
            produces: spec.produces,
            parse,
            defaults,
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

    #[test]
    fn nearest_suggests_a_close_name_only() {
        let mut registry = Registry::default();
        let spec = |name| SystemSpec { name, stage: ApfnSet::Sense, summary: "", needs: &[], produces: &[] };
        registry.register::<NoParams, _, _>(spec("lidar"), || {});
        registry.register::<NoParams, _, _>(spec("odometry"), || {});
        assert_eq!(registry.nearest("lidr"), Some("lidar"));
        assert_eq!(registry.nearest("odometri"), Some("odometry"));
        assert_eq!(registry.nearest("completely_else"), None);
    }
}
