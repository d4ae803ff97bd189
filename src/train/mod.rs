//! Training loops driven by the command line, each reading top to bottom: PF-net's supervised
//! pretraining on simulated episodes, and the collection of those episodes to disk.

pub mod collect;
pub mod curves;
pub mod episodes;
pub mod pfnet;
