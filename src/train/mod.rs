//! Training loops driven by the command line, each reading top to bottom: PF-net's supervised
//! pretraining on simulated episodes.

pub mod curves;
pub mod episodes;
pub mod pfnet;
