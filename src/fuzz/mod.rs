//! Fuzzing the loaders on stable Rust: every kind of file a user hands apfn (map YAML + image,
//! scene, schedule, eval, sweep, replay log and bag, PF-net checkpoint, SAC policy, training
//! config, episode collection) is mutated from valid files and loaded as the CLI loads it, with
//! panics caught and every input timed. `apfn fuzz` runs it; `tests/fuzz.rs` is its smoke test.

mod learning_files;
mod mutate;
mod run;
mod sample;
mod targets;

pub use mutate::{corpus_words, mutate};
pub use run::{FuzzOptions, HANG_FACTOR, TargetReport, fuzz_target};
pub use sample::Sample;
pub use targets::{TARGETS, Target, target};
