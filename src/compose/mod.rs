//! Composition: the system registry, schedule files (`systems/*.ron`) and scene files
//! (`scenes/*.ron`), all validated into typed values before an `App` exists; then spawning.

mod catalog;
mod error;
mod paths;
mod registry;
mod scene;
mod schedule;
mod spawn;

pub use catalog::standard_registry;
pub use error::{ComposeError, read_ron, read_text};
pub use paths::{relative_to_file, tidy};
pub use registry::{ConfiguredSystem, RegisteredSystem, Registry, StepSlot, SystemSpec};
pub use scene::{LoadedScene, MapSource, NamedMap, Scene, some_path};
pub use schedule::{Pipeline, PipelineStep};
pub use spawn::{MapName, NETWORK_RESOLUTION_M, map_layers, spawn_scene};
