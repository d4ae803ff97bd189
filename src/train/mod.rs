//! Training loops driven by the command line, each reading top to bottom: PF-net's supervised
//! pretraining on simulated episodes, the collection of those episodes to disk, and the SAC agent.

pub mod collect;
pub mod curves;
pub mod episodes;
pub mod log;
pub mod pfnet;
pub mod sac;
