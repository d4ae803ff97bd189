//! Seeded procedural apartments: the embedded default maps, in disjoint seen and unseen seed ranges.
