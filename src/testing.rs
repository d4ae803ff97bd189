//! Tiny worlds shared by unit tests, integration tests and benches.

use crate::world::OccupancyMap;

/// A 2 m × 1.5 m room at 0.1 m/cell with a one-cell wall all round and a 0.3 m pillar.
pub fn tiny_room() -> OccupancyMap {
    OccupancyMap::from_ascii(
        0.1,
        "
        ####################
        #..................#
        #..................#
        #..................#
        #..........###.....#
        #..........###.....#
        #..........###.....#
        #..................#
        #..................#
        #..................#
        #..................#
        #..................#
        #..................#
        #..................#
        ####################
        ",
    )
}
