//! apfn: active robot localization on bevy_ecs.
//!
//! Below the stages: `params` (the contract of a system's parameters) and `stage` (`ApfnSet`,
//! the stages of one agent step). The stages, in dataflow order: the `world` (maps, robots), `sense` (LiDAR, occupancy grid,
//! depth, odometry), `particles` (the filter), `belief` (its projection for the agent), `agent` (policies), `act` (drive and physics),
//! then `episode` bookkeeping; `compose` turns RON files into schedules; `eval` writes results
//! tables and `sweep` repeats them across seeds as independent jobs; `replay` runs the filter
//! on recorded logs; `limits` bounds every count a file can set and `fuzz` mutates every input
//! file to check the loaders; `cli` is the binary's.

// Systems state their inputs as query tuples; naming each tuple would hide what a system reads.
#![allow(clippy::type_complexity)]

pub mod limits;
pub mod params;

pub mod stage;

pub mod world;

pub mod sense;

pub mod particles;

pub mod belief;

pub mod agent;

pub mod act;

pub mod episode;

pub mod nn;

pub mod train;

pub mod compose;

pub mod eval;

pub mod sweep;

pub mod replay;

pub mod fuzz;

pub mod plugin;

pub mod cli;

// Tiny worlds for tests: compiled for this crate's unit tests and, through the `testing` feature
// (switched on by the self dev-dependency in Cargo.toml), for tests/ and benches/; never in a
// plain build.
#[cfg(any(test, feature = "testing"))]
pub mod testing;
