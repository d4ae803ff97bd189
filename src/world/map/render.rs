//! Draws an occupancy map as an image, north up: free white, occupied black, unknown grey,
//! and (optionally) the space a robot can reach tinted light blue.

use crate::world::map::{Cell, OccupancyMap, TraversableMap};
use image::{Rgb, RgbImage};

/// One pixel per cell; image row 0 is the map's top row.
pub fn render(map: &OccupancyMap, trav: Option<&TraversableMap>) -> RgbImage {
    let reachable = |i: usize, j: usize| trav.is_some_and(|t| t.is_traversable(i, j));
    RgbImage::from_fn(map.width as u32, map.height as u32, |x, row| {
        let (i, j) = (x as usize, map.height - 1 - row as usize);
        match map.get(i, j) {
            Cell::Free if reachable(i, j) => Rgb([214, 232, 255]),
            Cell::Free => Rgb([255, 255, 255]),
            Cell::Occupied => Rgb([0, 0, 0]),
            Cell::Unknown => Rgb([150, 150, 150]),
        }
    })
}
