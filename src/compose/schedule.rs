//! Schedule files (`systems/*.ron`): an ordered list of `(name, params)` steps, decoded against
//! the registry into a validated `Pipeline` before any `App` exists.
//!
//! ```ron
//! Schedule(steps: [("odometry", (trans_noise_m: 0.01)), ("lidar", ()), ("random_policy", ())])
//! ```

use crate::compose::error::{ComposeError, read_text};
use crate::compose::registry::{ConfiguredSystem, Registry, StepSlot, chain_slots};
use crate::params::StepData;
use crate::stage::ApfnSet;
use bevy::prelude::*;
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, SeqAccess, Visitor};
use std::fmt;
use std::path::{Path, PathBuf};

/// One decoded step of a schedule.
pub struct PipelineStep {
    pub name: &'static str,
    pub stage: ApfnSet,
    pub system: Box<dyn ConfiguredSystem>,
}

impl Clone for PipelineStep {
    fn clone(&self) -> Self {
        Self { name: self.name, stage: self.stage, system: self.system.boxed_clone() }
    }
}

/// A validated schedule: the systems of one agent step, in order.
#[derive(Clone)]
pub struct Pipeline {
    pub source: PathBuf,
    pub steps: Vec<PipelineStep>,
}

impl Pipeline {
    /// Reads and validates a schedule file.
    pub fn load(path: &Path, registry: &Registry) -> Result<Pipeline, ComposeError> {
        Self::parse(&read_text(path)?, path, registry)
    }

    /// Decodes schedule text; `path` only labels errors.
    pub fn parse(text: &str, path: &Path, registry: &Registry) -> Result<Pipeline, ComposeError> {
        let mut de = ron::Deserializer::from_str(text).map_err(|e| ComposeError::from_ron(path, e))?;
        let steps = de
            .deserialize_struct("Schedule", &["steps"], ScheduleVisitor { registry })
            .and_then(|steps| de.end().map(|_| steps))
            .map_err(|e| ComposeError::from_ron(path, de.span_error(e)))?;
        let pipeline = Pipeline { source: path.to_owned(), steps };
        pipeline.validate(registry)?;
        Ok(pipeline)
    }

    /// Checks what parsing cannot: no step twice, stages in order, and every step's needs met
    /// by an earlier step.
    fn validate(&self, registry: &Registry) -> Result<(), ComposeError> {
        let error = |index: usize, name: &str, message: String| ComposeError::Step {
            path: self.source.clone(),
            index: index + 1,
            name: name.to_owned(),
            message,
        };
        let mut produced: Vec<StepData> = Vec::new();
        for (index, step) in self.steps.iter().enumerate() {
            if self.steps[..index].iter().any(|s| s.name == step.name) {
                return Err(error(index, step.name, "appears twice; a system runs once per step".into()));
            }
            if let Some(later) = self.steps[..index].iter().find(|s| s.stage > step.stage) {
                return Err(error(
                    index,
                    step.name,
                    format!(
                        "is a {:?} system but comes after `{}` ({:?}); stages run in the order {:?}",
                        step.stage,
                        later.name,
                        later.stage,
                        ApfnSet::ALL
                    ),
                ));
            }
            let entry = registry.get(step.name).expect("parsed steps are registered");
            let always = entry.needs.iter().map(|need| (need, ""));
            let param_needs = step.system.param_needs();
            for (need, why) in always.chain(param_needs.iter().map(|need| (need, " with these parameters"))) {
                if !produced.contains(need) {
                    let providers: Vec<_> = registry
                        .entries()
                        .iter()
                        .filter(|e| e.produces.contains(need))
                        .map(|e| e.name)
                        .collect();
                    return Err(error(
                        index,
                        step.name,
                        format!(
                            "needs {}{why}, which no earlier step produces; add one of {providers:?} before it",
                            need.name
                        ),
                    ));
                }
            }
            produced.extend(&entry.produces);
        }
        Ok(())
    }

    /// Puts system `new` with `params` in the slot of step `old` (e.g. `pfnet_likelihood` for
    /// `mcl_likelihood_field`), then checks the schedule again: the new step must fit the slot's
    /// stage and find what it needs earlier; `new` = `old` just changes its parameters (fields
    /// left out take the system's defaults). Returns whether this pipeline runs `old`.
    pub fn replace_step(
        &mut self,
        old: &str,
        new: &str,
        params: &str,
        registry: &Registry,
    ) -> Result<bool, String> {
        self.edit_step(old, new, params, registry, |steps, index, step| steps[index] = step)
    }

    /// Inserts system `new` with `params` right after step `after` (e.g. `augmented_recovery`
    /// after `mcl_likelihood_field`), then checks the schedule again as [`Self::replace_step`]
    /// does. Returns whether this pipeline runs `after`.
    pub fn insert_step_after(
        &mut self,
        after: &str,
        new: &str,
        params: &str,
        registry: &Registry,
    ) -> Result<bool, String> {
        self.edit_step(after, new, params, registry, |steps, index, step| steps.insert(index + 1, step))
    }

    /// Finds step `at`, builds `new` from `params`, lets `edit` place it, and validates; a failed
    /// edit leaves the schedule as it was.
    fn edit_step(
        &mut self,
        at: &str,
        new: &str,
        params: &str,
        registry: &Registry,
        edit: impl FnOnce(&mut Vec<PipelineStep>, usize, PipelineStep),
    ) -> Result<bool, String> {
        let known = |name: &str| {
            registry.get(name).ok_or_else(|| {
                let hint =
                    registry.nearest(name).map(|n| format!(" (did you mean `{n}`?)")).unwrap_or_default();
                format!("unknown system `{name}`{hint}")
            })
        };
        let (at_entry, new_entry) = (known(at)?, known(new)?);
        let Some(index) = self.steps.iter().position(|s| s.name == at_entry.name) else {
            return Ok(false);
        };
        let mut de = ron::Deserializer::from_str(params).map_err(|e| e.to_string())?;
        let system = parse_step_params(new_entry, &mut de)?;
        let step = PipelineStep { name: new_entry.name, stage: new_entry.stage, system };
        let kept = self.steps.clone();
        edit(&mut self.steps, index, step);
        if let Err(e) = self.validate(registry) {
            self.steps = kept;
            return Err(e.to_string());
        }
        Ok(true)
    }

    /// Adds every step to `Update`, each in its stage and in file order.
    pub fn install(&self, app: &mut App) {
        for (index, step) in self.steps.iter().enumerate() {
            step.system.install(app, StepSlot(index), step.stage);
        }
        chain_slots(app, Update, self.steps.len());
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.steps.iter().map(|s| s.name).collect()
    }
}

struct ScheduleVisitor<'r> {
    registry: &'r Registry,
}

impl<'de> Visitor<'de> for ScheduleVisitor<'_> {
    type Value = Vec<PipelineStep>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("Schedule(steps: [(\"system_name\", (params…)), …])")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut steps = None;
        while let Some(key) = map.next_key::<String>()? {
            match key.as_str() {
                "steps" if steps.is_none() => steps = Some(map.next_value_seed(StepsSeed(self.registry))?),
                "steps" => return Err(de::Error::duplicate_field("steps")),
                other => return Err(de::Error::unknown_field(other, &["steps"])),
            }
        }
        steps.ok_or_else(|| de::Error::missing_field("steps"))
    }
}

struct StepsSeed<'r>(&'r Registry);

impl<'de> DeserializeSeed<'de> for StepsSeed<'_> {
    type Value = Vec<PipelineStep>;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Self::Value, D::Error> {
        deserializer.deserialize_seq(self)
    }
}

impl<'de> Visitor<'de> for StepsSeed<'_> {
    type Value = Vec<PipelineStep>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a list of (\"system_name\", (params…)) steps")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut steps = Vec::new();
        while let Some(step) = seq.next_element_seed(StepSeed(self.0))? {
            steps.push(step);
        }
        Ok(steps)
    }
}

struct StepSeed<'r>(&'r Registry);

impl<'de> DeserializeSeed<'de> for StepSeed<'_> {
    type Value = PipelineStep;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Self::Value, D::Error> {
        deserializer.deserialize_tuple(2, self)
    }
}

impl<'de> Visitor<'de> for StepSeed<'_> {
    type Value = PipelineStep;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a step (\"system_name\", (params…))")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let name: String = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(0, &self))?;
        let Some(entry) = self.0.get(&name) else {
            let hint = self.0.nearest(&name).map(|n| format!(" (did you mean `{n}`?)")).unwrap_or_default();
            return Err(de::Error::custom(format!(
                "unknown system `{name}`{hint}; known systems: {}",
                self.0.names().join(", ")
            )));
        };
        let system = seq.next_element_seed(ParamsSeed(entry))?.ok_or_else(|| {
            de::Error::custom(format!("`{name}` needs its parameters: write `()` for defaults"))
        })?;
        Ok(PipelineStep { name: entry.name, stage: entry.stage, system })
    }
}

struct ParamsSeed<'r>(&'r crate::compose::registry::RegisteredSystem);

impl<'de> DeserializeSeed<'de> for ParamsSeed<'_> {
    type Value = Box<dyn ConfiguredSystem>;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Self::Value, D::Error> {
        parse_step_params(self.0, deserializer).map_err(de::Error::custom)
    }
}

/// Decodes `entry`'s parameters, naming the field a decoding error is in: the schedule file's
/// line and column point at the value, but an eval config's `overrides` hold the parameters as
/// text of their own, where only the field's name can say which value is wrong.
fn parse_step_params<'de, D: Deserializer<'de>>(
    entry: &crate::compose::registry::RegisteredSystem,
    deserializer: D,
) -> Result<Box<dyn ConfiguredSystem>, String> {
    let mut track = serde_path_to_error::Track::new();
    let tracked = serde_path_to_error::Deserializer::new(deserializer, &mut track);
    let mut erased = <dyn erased_serde::Deserializer>::erase(tracked);
    entry.parse_params(&mut erased).map_err(|e| {
        let field = track.path().to_string();
        match field.as_str() {
            "." | "?" => format!("parameters of `{}`: {e}", entry.name),
            _ => format!("parameters of `{}`, field `{field}`: {e}", entry.name),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compose::standard_registry;

    fn parse(text: &str) -> Result<Pipeline, ComposeError> {
        Pipeline::parse(text, Path::new("test.ron"), &standard_registry())
    }

    fn message(text: &str) -> String {
        parse(text).err().expect("schedule must be rejected").to_string()
    }

    #[test]
    fn schedule_parses_steps_in_order_with_params() {
        let p = parse(
            r#"Schedule(steps: [("lidar", ()), ("init_particles", ()), ("resample", (alpha: 1.0)), ("random_policy", ())])"#,
        );
        let p = p.expect("valid schedule");
        assert_eq!(p.names(), ["lidar", "init_particles", "resample", "random_policy"]);
        assert!(p.steps[2].system.params_ron().contains("alpha: 1.0"), "given parameters are kept");
    }

    #[test]
    fn schedule_unknown_system_names_position_and_suggests() {
        let m = message("Schedule(steps: [\n  (\"lidr\", ()),\n])");
        assert!(m.starts_with("test.ron:2:"), "error must point at line 2: {m}");
        assert!(m.contains("did you mean `lidar`"), "nearest name suggested: {m}");
        assert!(m.contains("odometry"), "known names listed: {m}");
    }

    #[test]
    fn schedule_bad_parameter_names_field_and_place() {
        let m = message("Schedule(steps: [\n (\"resample\", (alpha: \"half\")),\n])");
        assert!(m.starts_with("test.ron:2:"), "error must point at line 2: {m}");
        assert!(m.contains("resample"), "the system is named: {m}");
        let m = message(r#"Schedule(steps: [("resample", (alfa: 0.5))])"#);
        assert!(m.contains("alfa") && m.contains("alpha"), "unknown field and the expected ones: {m}");
    }

    #[test]
    fn schedule_out_of_range_parameter_names_field_and_place() {
        let m = message("Schedule(steps: [\n (\"resample\", (alpha: 1.5)),\n])");
        assert!(m.starts_with("test.ron:2:"), "error must point at line 2: {m}");
        assert!(m.contains("`resample`") && m.contains("resample.alpha") && m.contains("[0, 1]"), "{m}");
        let m = message(r#"Schedule(steps: [("lidar", (range_min_m: 6.0, range_max_m: 5.0))])"#);
        assert!(m.contains("range_min_m < range_max_m"), "{m}");
        let m = message(r#"Schedule(steps: [("odometry", (rot_noise_deg: -5.0))])"#);
        assert!(m.contains("rot_noise_deg") && m.contains("≥ 0"), "{m}");
    }

    #[test]
    fn every_registered_default_passes_its_own_check() {
        for entry in standard_registry().entries() {
            let mut de = ron::Deserializer::from_str("()").expect("valid RON");
            let mut erased = <dyn erased_serde::Deserializer>::erase(&mut de);
            let parsed = entry.parse_params(&mut erased);
            assert!(parsed.is_ok(), "`{}` rejects its own defaults: {:?}", entry.name, parsed.err());
        }
    }

    #[test]
    fn replace_step_changes_parameters_or_systems_and_checks_them() {
        let registry = standard_registry();
        let mut p = parse(
            r#"Schedule(steps: [("lidar", ()), ("init_particles", ()), ("mcl_likelihood_field", ()), ("resample", (alpha: 1.0))])"#,
        )
        .expect("valid schedule");
        let mut replace = |old, new, params| p.replace_step(old, new, params, &registry);
        assert_eq!(replace("resample", "resample", "(alpha: 0.25)"), Ok(true));
        assert_eq!(replace("depth", "depth", "()"), Ok(false), "a step the schedule lacks");
        let e = replace("resample", "resample", "(alpha: 2.0)").expect_err("out of range");
        assert!(e.contains("resample.alpha"), "{e}");
        let e = replace("resampel", "resample", "()").expect_err("unknown system");
        assert!(e.contains("did you mean `resample`"), "{e}");
        assert_eq!(replace("mcl_likelihood_field", "mcl_beam_model", "()"), Ok(true));
        let e = replace("mcl_beam_model", "pfnet_likelihood", "()").expect_err("no local grid");
        assert!(e.contains("needs LocalGrid"), "{e}");
        assert!(p.steps[3].system.params_ron().contains("alpha: 0.25"), "{}", p.steps[3].system.params_ron());
        assert_eq!(p.names()[2], "mcl_beam_model");
    }

    #[test]
    fn insert_step_after_adds_a_step_and_checks_the_schedule() {
        let registry = standard_registry();
        let mut p = parse(
            r#"Schedule(steps: [("lidar", ()), ("init_particles", ()), ("mcl_likelihood_field", ()), ("resample", ())])"#,
        )
        .expect("valid schedule");
        let mut insert = |after, new, params| p.insert_step_after(after, new, params, &registry);
        assert_eq!(insert("depth", "augmented_recovery", "()"), Ok(false), "a step the schedule lacks");
        let e = insert("mcl_likelihood_field", "augmented_recovery", "(alpha_slow: 0.5, alpha_fast: 0.1)")
            .expect_err("fast below slow");
        assert!(e.contains("alpha_fast"), "{e}");
        let e = insert("lidar", "augmented_recovery", "()").expect_err("before any particles");
        assert!(e.contains("needs ParticleSet"), "{e}");
        let e = insert("init_particles", "init_particles", "()").expect_err("a system runs once");
        assert!(e.contains("appears twice"), "{e}");
        assert_eq!(
            p.names(),
            ["lidar", "init_particles", "mcl_likelihood_field", "resample"],
            "failures change nothing"
        );
        assert_eq!(
            p.insert_step_after("mcl_likelihood_field", "augmented_recovery", "()", &registry),
            Ok(true)
        );
        assert_eq!(
            p.names(),
            ["lidar", "init_particles", "mcl_likelihood_field", "augmented_recovery", "resample"]
        );
    }

    #[test]
    fn schedule_rejects_wrong_stage_order() {
        let m = message(r#"Schedule(steps: [("random_policy", ()), ("lidar", ())])"#);
        assert!(m.contains("step 2 `lidar`") && m.contains("random_policy"), "{m}");
    }

    #[test]
    fn schedule_rejects_unmet_needs() {
        let m = message(r#"Schedule(steps: [("lidar", ()), ("transition", ())])"#);
        assert!(m.contains("needs ParticleSet") && m.contains("init_particles"), "{m}");
        let m = message(r#"Schedule(steps: [("init_particles", ()), ("mcl_likelihood_field", ())])"#);
        assert!(
            m.contains("needs LidarScan") && m.contains("lidar"),
            "a likelihood needs a sensor first: {m}"
        );
    }

    #[test]
    fn schedule_rejects_goalnav_steering_by_an_estimate_no_step_makes() {
        let steps = |goalnav: &str, filter: &str| {
            format!(
                r#"Schedule(steps: [("lidar", ()), ("init_particles", ()), {filter}("goalnav_policy", {goalnav})])"#
            )
        };
        let m = message(&steps("(use_estimate: true)", ""));
        assert!(
            m.starts_with("test.ron: step 3 `goalnav_policy`: needs PoseEstimate with these parameters")
                && m.contains("[\"estimate\"]"),
            "names the file, the step, the missing data and its maker: {m}"
        );
        parse(&steps("()", "")).expect("steering by the true pose needs no estimate");
        parse(&steps("(use_estimate: true)", r#"("estimate", ()), "#)).expect("an estimate step comes first");
        let registry = standard_registry();
        let mut p = parse(&steps("()", "")).expect("valid");
        let e = p.replace_step("goalnav_policy", "goalnav_policy", "(use_estimate: true)", &registry);
        let e = e.expect_err("no estimate");
        assert!(e.contains("needs PoseEstimate"), "overrides are validated too: {e}");
    }

    #[test]
    fn every_shipped_schedule_validates() {
        let registry = standard_registry();
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("systems");
        let mut count = 0;
        for file in std::fs::read_dir(&dir).expect("systems/ exists") {
            let path = file.expect("a directory entry").path();
            if path.extension().is_some_and(|x| x == "ron") {
                Pipeline::load(&path, &registry).unwrap_or_else(|e| panic!("{e}"));
                count += 1;
            }
        }
        assert!(count >= 10, "systems/ ships the pipelines ({count} found)");
    }

    #[test]
    fn a_wrong_parameter_value_is_named_by_its_field() {
        let m = message(r#"Schedule(steps: [("lidar", (rays: 90, range_max_m: "far"))])"#);
        assert!(
            m.starts_with("test.ron:1:")
                && m.contains("parameters of `lidar`, field `range_max_m`: Expected float"),
            "the file's position and the field: {m}"
        );
        let mut p = parse(r#"Schedule(steps: [("lidar", ())])"#).expect("valid");
        let e =
            p.replace_step("lidar", "lidar", "(rays: -3)", &standard_registry()).expect_err("negative rays");
        assert!(
            e.starts_with("parameters of `lidar`, field `rays`: "),
            "a replacement's text has no file: {e}"
        );
        let e = p.replace_step("lidar", "lidar", "(rays: 90)", &standard_registry());
        assert_eq!(e, Ok(true), "good parameters still replace the step");
    }

    #[test]
    fn schedule_rejects_duplicates_and_syntax_errors() {
        assert!(message(r#"Schedule(steps: [("lidar", ()), ("lidar", ())])"#).contains("twice"));
        assert!(message(r#"Schedule(steps: [("lidar", ()"#).starts_with("test.ron:1:"));
    }
}
