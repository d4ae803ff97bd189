//! Seeded procedural apartments, the embedded default maps: a floor plan from recursive binary
//! space partitioning (rooms, corridor or open plan, doors), then furniture that never blocks a
//! door or cuts a room in two, then (by default) a realism layer that makes it look like a SLAM
//! map: uneven walls with small gaps, furniture as outlines and legs, clutter. Training ("seen")
//! and test ("unseen") maps use disjoint seed ranges.

mod apartment;
mod furniture;
mod params;
mod realism;
mod rect;
mod rooms;

pub use apartment::generate_apartment;
pub use params::{ApartmentParams, ApartmentParamsError, RealismParams, SEEN_SEEDS, Split, UNSEEN_SEEDS};
