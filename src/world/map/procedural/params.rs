//! What procedural apartments look like, and which seeds are for training and which for testing.

use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Seeds of the training ("seen") apartments.
pub const SEEN_SEEDS: Range<u64> = 0..1_000_000;
/// Seeds of the test ("unseen") apartments; disjoint from [`SEEN_SEEDS`].
pub const UNSEEN_SEEDS: Range<u64> = 1_000_000..2_000_000;
const _: () = assert!(SEEN_SEEDS.end <= UNSEEN_SEEDS.start, "seed ranges must be disjoint");

/// Which side of the train/test divide an apartment seed lies on (the paper's seen/unseen maps).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Seen,
    Unseen,
}

impl Split {
    /// The seed range of this split.
    pub fn seeds(&self) -> Range<u64> {
        match self {
            Split::Seen => SEEN_SEEDS,
            Split::Unseen => UNSEEN_SEEDS,
        }
    }

    /// The split a seed belongs to, or `None` for seeds outside both ranges.
    pub fn of_seed(seed: u64) -> Option<Split> {
        [Split::Seen, Split::Unseen].into_iter().find(|s| s.seeds().contains(&seed))
    }
}

/// Shape of procedural apartments. Out-of-range values are clamped by [`generate_apartment`];
/// call [`ApartmentParams::validate`] first to reject them instead.
///
/// [`generate_apartment`]: super::generate_apartment
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ApartmentParams {
    /// Cell side of the generated grid, metres (design: fine simulation grid 0.02–0.05 m).
    pub resolution_m: f32,
    /// Shortest side of the apartment's bounding box, metres (issue spec: 6 m).
    pub min_side_m: f32,
    /// Longest side of the apartment's bounding box, metres (issue spec: 20 m).
    pub max_side_m: f32,
    /// Largest long-side / short-side ratio of the bounding box (our choice: 2).
    pub max_aspect: f32,
    /// Fewest rooms, corridor not counted (our choice: 2).
    pub min_rooms: usize,
    /// Most rooms, corridor not counted (our choice: 10).
    pub max_rooms: usize,
    /// Mean floor area per room that sets the room count, m² (our choice: 20 m², bath and hall included).
    pub mean_room_area_m2: f32,
    /// Shortest side of any room, metres, wall centre to wall centre (our choice: 2.2 m).
    pub min_room_side_m: f32,
    /// Thickness of every wall, metres (issue spec: 0.1 m).
    pub wall_thickness_m: f32,
    /// Narrowest door gap, metres (issue spec: 0.8 m; robot diameter 0.36 m).
    pub door_min_m: f32,
    /// Widest door gap, metres (issue spec: 1.0 m).
    pub door_max_m: f32,
    /// Narrowest corridor, metres (our choice: 1.1 m, a usual flat's hallway).
    pub corridor_min_m: f32,
    /// Widest corridor, metres (our choice: 1.5 m).
    pub corridor_max_m: f32,
    /// Probability that the outline is an L rather than a rectangle (our choice: 0.35).
    pub l_shape_probability: f64,
    /// Probability of the corridor layout; otherwise the largest room opens widely onto one or two
    /// neighbours (open plan) (our choice: 0.5).
    pub corridor_probability: f64,
    /// Probability that a pair of adjacent rooms gets a door beyond those needed to connect
    /// every room, making loops (our choice: 0.25).
    pub extra_door_probability: f64,
    /// Furniture pieces per m² of room floor, 1/m² (our choice: 0.15; 0 gives empty rooms).
    pub furniture_per_m2: f32,
    /// Least gap between two pieces of furniture, or between furniture and a wall it does not
    /// touch, metres (our choice: 0.6 m = robot diameter 0.36 m + margin).
    pub furniture_clearance_m: f32,
    /// Probability that a room larger than 20 m² gets one or two pillars (our choice: 0.3).
    pub pillar_probability: f64,
    /// Band of unknown cells around the apartment, metres (issue spec: 0.5 m).
    pub margin_m: f32,
    /// How the clean plan is roughened to look like a SLAM map. Off in [`Default`], so the
    /// committed MCL tables reproduce (`realism: ()` in a scene file turns it on with its own
    /// defaults); on in [`ApartmentParams::paper_size`], which PF-net trains on.
    pub realism: RealismParams,
}

impl Default for ApartmentParams {
    fn default() -> Self {
        Self {
            resolution_m: 0.05,
            min_side_m: 6.0,
            max_side_m: 20.0,
            max_aspect: 2.0,
            min_rooms: 2,
            max_rooms: 10,
            mean_room_area_m2: 20.0,
            min_room_side_m: 2.2,
            wall_thickness_m: 0.1,
            door_min_m: 0.8,
            door_max_m: 1.0,
            corridor_min_m: 1.1,
            corridor_max_m: 1.5,
            l_shape_probability: 0.35,
            corridor_probability: 0.5,
            extra_door_probability: 0.25,
            furniture_per_m2: 0.15,
            furniture_clearance_m: 0.6,
            pillar_probability: 0.3,
            margin_m: 0.5,
            realism: RealismParams::none(),
        }
    }
}

/// How a clean apartment is roughened to look like a 0.05 m SLAM map of a furnished flat
/// (`aws_small_house`, `aws_bookstore`): walls of uneven thickness with small gaps, furniture
/// seen as outlines, legs and edges, round and slanted tables, clutter. A rate or probability
/// of 0 switches its feature off; all of them 0, or `enabled: false`, leaves the map unchanged.
/// Nothing here may cut the robot's free space in two: see the realism module.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RealismParams {
    /// Whether the layer runs at all (our choice: true, so that a learned model trained on
    /// procedural maps sees SLAM-like maps; false reproduces maps made before the layer).
    pub enabled: bool,
    /// Share of wall runs (0.3–1.5 m stretches along a wall face) drawn thinner (60 %) or
    /// thicker (40 %) than nominal (our choice: 0.4; SLAM walls in the AWS maps are mostly one or
    /// two cells thick, in places up to four).
    pub wall_jitter_probability: f64,
    /// Most extra thickness a thicker wall run grows into its room, metres (our choice:
    /// 0.1 m = 2 cells, the spread seen in the AWS maps; at most 0.3 m).
    pub wall_thicken_max_m: f32,
    /// Chance, per cell of wall face, of a one-cell bump into the room or notch into the wall
    /// (our choice: 0.04, a few per metre, like SLAM's ragged wall edges).
    pub wall_noise_probability: f64,
    /// Small gaps cut through walls per metre of wall face, 1/m (our choice: 0.1; an interior
    /// wall has two faces; SLAM walls show a few unobserved cells every few metres).
    pub wall_gaps_per_m: f32,
    /// Narrowest wall gap, metres (our choice: 0.05 m = one cell).
    pub wall_gap_min_m: f32,
    /// Widest wall gap, metres (our choice: 0.15 m; at most 0.3 m so it stays narrower than the
    /// robot's 0.36 m diameter and never becomes a passage).
    pub wall_gap_max_m: f32,
    /// Chance that a solid piece (shelf, counter, pillar, and beds, sofas, tables drawn neither
    /// as edges nor legs) is a one-cell outline with an unknown interior rather than a black block
    /// (our choice: 0.9; the AWS maps show furniture as black outlines around unknown space,
    /// hardly ever as solid blocks).
    pub outline_probability: f64,
    /// Chance that a bed or sofa shows only as one-cell lines on 1–3 of its room-facing sides,
    /// the floor beneath free (our choice: 0.5; a low LiDAR sees a sofa's back or a bed's edge).
    pub partial_outline_probability: f64,
    /// Chance that a table or desk shows only its legs, 2–4-cell dots at its corners (our choice:
    /// 0.6; the AWS bookstore's tables and chairs are dots).
    pub legs_probability: f64,
    /// Chance, per side of a square-cornered table shown by its legs, of chairs along that side,
    /// each as four leg dots (our choice: 0.6).
    pub chair_probability: f64,
    /// Chance that a table is round, a disc outline with an unknown interior (our choice: 0.25).
    pub round_table_probability: f64,
    /// Chance that a free-standing table stands slanted, rotated 10°–45° within its footprint
    /// (our choice: 0.3).
    pub slant_probability: f64,
    /// Small clutter blobs per m² of floor, 1/m² (our choice: 0.08, a few per room: bins,
    /// plant pots, bags; half against a wall, half free-standing).
    pub clutter_per_m2: f32,
    /// Largest clutter blob side, metres (our choice: 0.15 m = 3 cells; at most 0.5 m).
    pub clutter_max_m: f32,
}

impl Default for RealismParams {
    fn default() -> Self {
        Self {
            enabled: true,
            wall_jitter_probability: 0.4,
            wall_thicken_max_m: 0.1,
            wall_noise_probability: 0.04,
            wall_gaps_per_m: 0.1,
            wall_gap_min_m: 0.05,
            wall_gap_max_m: 0.15,
            outline_probability: 0.9,
            partial_outline_probability: 0.5,
            legs_probability: 0.6,
            chair_probability: 0.6,
            round_table_probability: 0.25,
            slant_probability: 0.3,
            clutter_per_m2: 0.08,
            clutter_max_m: 0.15,
        }
    }
}

impl RealismParams {
    /// Every feature off: the same maps as `enabled: false`, through the layer's code path.
    pub fn none() -> Self {
        Self {
            enabled: true,
            wall_jitter_probability: 0.0,
            wall_noise_probability: 0.0,
            wall_gaps_per_m: 0.0,
            outline_probability: 0.0,
            partial_outline_probability: 0.0,
            legs_probability: 0.0,
            chair_probability: 0.0,
            round_table_probability: 0.0,
            slant_probability: 0.0,
            clutter_per_m2: 0.0,
            ..Self::default()
        }
    }

    /// Checks every field against the range the layer supports.
    pub fn validate(&self) -> Result<(), ApartmentParamsError> {
        let bad = |field, expected, got: String| Err(ApartmentParamsError { field, expected, got });
        let r = self;
        let in_range = |x: f32, lo: f32, hi: f32| x.is_finite() && (lo..=hi).contains(&x);
        for (field, p) in [
            ("realism.wall_jitter_probability", r.wall_jitter_probability),
            ("realism.wall_noise_probability", r.wall_noise_probability),
            ("realism.outline_probability", r.outline_probability),
            ("realism.partial_outline_probability", r.partial_outline_probability),
            ("realism.legs_probability", r.legs_probability),
            ("realism.chair_probability", r.chair_probability),
            ("realism.round_table_probability", r.round_table_probability),
            ("realism.slant_probability", r.slant_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return bad(field, "in [0, 1]", p.to_string());
            }
        }
        if !in_range(r.wall_thicken_max_m, 0.0, 0.3) {
            return bad("realism.wall_thicken_max_m", "in [0, 0.3] m", r.wall_thicken_max_m.to_string());
        }
        if !in_range(r.wall_gaps_per_m, 0.0, 10.0) {
            return bad("realism.wall_gaps_per_m", "in [0, 10] /m", r.wall_gaps_per_m.to_string());
        }
        if !in_range(r.wall_gap_min_m, 0.0, r.wall_gap_max_m) {
            return bad("realism.wall_gap_min_m", "in [0, wall_gap_max_m] m", r.wall_gap_min_m.to_string());
        }
        if !in_range(r.wall_gap_max_m, r.wall_gap_min_m, 0.3) {
            return bad(
                "realism.wall_gap_max_m",
                "in [wall_gap_min_m, 0.3] m (narrower than the robot)",
                r.wall_gap_max_m.to_string(),
            );
        }
        if !in_range(r.clutter_per_m2, 0.0, 10.0) {
            return bad("realism.clutter_per_m2", "in [0, 10] /m²", r.clutter_per_m2.to_string());
        }
        if !in_range(r.clutter_max_m, 0.0, 0.5) {
            return bad("realism.clutter_max_m", "in [0, 0.5] m", r.clutter_max_m.to_string());
        }
        Ok(())
    }
}

/// A parameter outside the range the generator supports.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("apartment params: `{field}` must be {expected}, got {got}")]
pub struct ApartmentParamsError {
    pub field: &'static str,
    pub expected: &'static str,
    pub got: String,
}

impl ApartmentParams {
    /// Checks every field against the range the generator supports.
    pub fn validate(&self) -> Result<(), ApartmentParamsError> {
        let bad = |field, expected, got: String| Err(ApartmentParamsError { field, expected, got });
        let d = self;
        let in_range = |x: f32, lo: f32, hi: f32| x.is_finite() && (lo..=hi).contains(&x);
        if !in_range(d.resolution_m, 0.005, 0.5) {
            return bad("resolution_m", "in [0.005, 0.5] m", d.resolution_m.to_string());
        }
        if !in_range(d.min_room_side_m, 1.0, 10.0) {
            return bad("min_room_side_m", "in [1, 10] m", d.min_room_side_m.to_string());
        }
        if !in_range(d.min_side_m, 2.0 * d.min_room_side_m, d.max_side_m) {
            return bad("min_side_m", "≥ 2·min_room_side_m and ≤ max_side_m", d.min_side_m.to_string());
        }
        if !in_range(d.max_side_m, d.min_side_m, 4000.0 * d.resolution_m) {
            return bad("max_side_m", "≤ 4000 cells", d.max_side_m.to_string());
        }
        if !in_range(d.max_aspect, 1.0, 10.0) {
            return bad("max_aspect", "in [1, 10]", d.max_aspect.to_string());
        }
        if d.min_rooms == 0 || d.min_rooms > d.max_rooms || d.max_rooms > 64 {
            return bad(
                "min_rooms/max_rooms",
                "1 ≤ min ≤ max ≤ 64",
                format!("{}..{}", d.min_rooms, d.max_rooms),
            );
        }
        if !in_range(d.mean_room_area_m2, 1.0, 1000.0) {
            return bad("mean_room_area_m2", "in [1, 1000] m²", d.mean_room_area_m2.to_string());
        }
        if !in_range(d.wall_thickness_m, d.resolution_m, 1.0) {
            return bad("wall_thickness_m", "in [resolution_m, 1] m", d.wall_thickness_m.to_string());
        }
        if !in_range(d.door_min_m, 2.0 * d.resolution_m, d.door_max_m) {
            return bad("door_min_m", "≥ 2 cells and ≤ door_max_m", d.door_min_m.to_string());
        }
        if !in_range(d.door_max_m, d.door_min_m, d.min_room_side_m - d.wall_thickness_m) {
            return bad("door_max_m", "≤ min_room_side_m − wall_thickness_m", d.door_max_m.to_string());
        }
        if !in_range(d.corridor_min_m, d.door_min_m, d.corridor_max_m) {
            return bad("corridor_min_m", "≥ door_min_m and ≤ corridor_max_m", d.corridor_min_m.to_string());
        }
        if !in_range(d.corridor_max_m, d.corridor_min_m, 10.0) {
            return bad("corridor_max_m", "in [corridor_min_m, 10] m", d.corridor_max_m.to_string());
        }
        for (field, p) in [
            ("l_shape_probability", d.l_shape_probability),
            ("corridor_probability", d.corridor_probability),
            ("extra_door_probability", d.extra_door_probability),
            ("pillar_probability", d.pillar_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return bad(field, "in [0, 1]", p.to_string());
            }
        }
        if !in_range(d.furniture_per_m2, 0.0, 10.0) {
            return bad("furniture_per_m2", "in [0, 10] /m²", d.furniture_per_m2.to_string());
        }
        if !in_range(d.furniture_clearance_m, 0.0, 10.0) {
            return bad("furniture_clearance_m", "in [0, 10] m", d.furniture_clearance_m.to_string());
        }
        if !in_range(d.margin_m, 0.0, 100.0) {
            return bad("margin_m", "in [0, 100] m", d.margin_m.to_string());
        }
        d.realism.validate()
    }

    /// The paper's size range: the authors kept Gibson scenes whose traversable bounding box is
    /// at most 10 m, so outlines of 5–10 m a side with 2–5 rooms of about 15 m² (small flats
    /// have smaller rooms). The bounding box, walls included, is at most 10.1 m, and the
    /// traversable one, inside the walls, under 10 m. Scan realism on; everything else as
    /// [`Default`], which stays at 6–20 m and clean so that committed results stay reproducible.
    pub fn paper_size() -> Self {
        Self {
            min_side_m: 5.0,
            max_side_m: 10.0,
            max_rooms: 5,
            mean_room_area_m2: 15.0,
            realism: RealismParams::default(),
            ..Self::default()
        }
    }
}

/// The parameters clamped into range and converted to whole cells: what the generator works with.
#[derive(Clone, Debug)]
pub(super) struct CellParams {
    pub resolution_m: f32,
    pub min_side_m: f32,
    pub max_side_m: f32,
    pub max_aspect: f32,
    pub min_rooms: usize,
    pub max_rooms: usize,
    pub mean_room_area_m2: f32,
    pub l_shape_probability: f64,
    pub corridor_probability: f64,
    pub extra_door_probability: f64,
    pub pillar_probability: f64,
    pub furniture_per_m2: f32,
    /// Shortest room side, cells.
    pub min_room: i32,
    /// A wall centred on grid line `X` covers cells `X − wall_lo .. X + wall_hi`.
    pub wall_lo: i32,
    pub wall_hi: i32,
    pub door_min: i32,
    pub door_max: i32,
    pub corridor_min: i32,
    pub corridor_max: i32,
    pub margin: i32,
    /// Furniture clearance, cells.
    pub clearance: i32,
    /// Least wall between a door and a corner, cells (0.15 m, our choice).
    pub door_corner: i32,
    /// How far the clear zone in front of a door reaches into each room, cells.
    pub keep_depth: i32,
    /// How far the clear zone extends beyond each side of a door, cells (0.2 m, our choice).
    pub keep_side: i32,
}

fn clamp_or(x: f32, lo: f32, hi: f32, fallback: f32) -> f32 {
    if x.is_finite() { x.clamp(lo, hi) } else { fallback }
}

impl CellParams {
    pub fn new(p: &ApartmentParams) -> Self {
        let d = ApartmentParams::default();
        let res = clamp_or(p.resolution_m, 0.005, 0.5, d.resolution_m);
        let cells = |m: f32| (m / res).round() as i32;
        let min_room_side = clamp_or(p.min_room_side_m, 1.0, 10.0, d.min_room_side_m);
        let max_side = clamp_or(p.max_side_m, 2.0 * min_room_side, 4000.0 * res, d.max_side_m);
        let min_side = clamp_or(p.min_side_m, 2.0 * min_room_side, max_side, d.min_side_m.min(max_side));
        let wall = cells(clamp_or(p.wall_thickness_m, res, 1.0, d.wall_thickness_m)).max(1);
        let door_min = cells(clamp_or(p.door_min_m, 2.0 * res, min_room_side, d.door_min_m)).max(2);
        let door_max = cells(clamp_or(p.door_max_m, 2.0 * res, min_room_side, d.door_max_m)).max(door_min);
        let corridor_min = cells(clamp_or(p.corridor_min_m, res, 10.0, d.corridor_min_m)).max(door_min);
        let corridor_max = cells(clamp_or(p.corridor_max_m, res, 10.0, d.corridor_max_m)).max(corridor_min);
        let clearance = cells(clamp_or(p.furniture_clearance_m, 0.0, 10.0, d.furniture_clearance_m));
        let min_rooms = p.min_rooms.clamp(1, 64);
        Self {
            resolution_m: res,
            min_side_m: min_side,
            max_side_m: max_side,
            max_aspect: clamp_or(p.max_aspect, 1.0, 10.0, d.max_aspect),
            min_rooms,
            max_rooms: p.max_rooms.clamp(min_rooms, 64),
            mean_room_area_m2: clamp_or(p.mean_room_area_m2, 1.0, 1000.0, d.mean_room_area_m2),
            l_shape_probability: p.l_shape_probability.clamp(0.0, 1.0),
            corridor_probability: p.corridor_probability.clamp(0.0, 1.0),
            extra_door_probability: p.extra_door_probability.clamp(0.0, 1.0),
            pillar_probability: p.pillar_probability.clamp(0.0, 1.0),
            furniture_per_m2: clamp_or(p.furniture_per_m2, 0.0, 10.0, d.furniture_per_m2),
            min_room: cells(min_room_side).max(2 * wall + 2),
            wall_lo: wall / 2,
            wall_hi: wall - wall / 2,
            door_min,
            door_max,
            corridor_min,
            corridor_max,
            margin: cells(clamp_or(p.margin_m, 0.0, 100.0, d.margin_m)).max(wall),
            clearance,
            door_corner: cells(0.15).max(1),
            keep_depth: clearance + cells(0.3),
            keep_side: cells(0.2),
        }
    }

    /// Area of `cells` grid cells, m².
    pub fn area_m2(&self, cells: i64) -> f32 {
        cells as f32 * self.resolution_m * self.resolution_m
    }

    /// A length in metres as whole cells.
    pub fn cells(&self, m: f32) -> i32 {
        (m / self.resolution_m).round() as i32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_ranges_are_disjoint_and_of_seed_agrees() {
        let (last_seen, first_unseen) = (SEEN_SEEDS.end - 1, UNSEEN_SEEDS.start);
        assert!(!UNSEEN_SEEDS.contains(&last_seen), "last seen seed {last_seen} is also unseen");
        assert!(!SEEN_SEEDS.contains(&first_unseen), "first unseen seed {first_unseen} is also seen");
        assert_eq!(Split::of_seed(0), Some(Split::Seen));
        assert_eq!(Split::of_seed(999_999), Some(Split::Seen));
        assert_eq!(Split::of_seed(1_000_000), Some(Split::Unseen));
        assert_eq!(Split::of_seed(1_999_999), Some(Split::Unseen));
        assert_eq!(Split::of_seed(2_000_000), None, "seeds past both ranges belong to neither");
        for split in [Split::Seen, Split::Unseen] {
            let r = split.seeds();
            assert_eq!(Split::of_seed(r.start), Some(split));
            assert_eq!(Split::of_seed(r.end - 1), Some(split));
        }
    }

    #[test]
    fn split_names_in_ron_are_snake_case() {
        assert_eq!(ron::to_string(&Split::Unseen).expect("serialise"), "unseen");
        assert_eq!(ron::from_str::<Split>("seen").expect("parse"), Split::Seen);
    }

    #[test]
    fn defaults_validate_and_bad_values_are_named() {
        assert_eq!(ApartmentParams::default().validate(), Ok(()));
        let p = ApartmentParams { door_min_m: 1.2, ..Default::default() };
        let err = p.validate().expect_err("door_min above door_max must be rejected");
        assert_eq!(err.field, "door_min_m");
        let p = ApartmentParams { corridor_probability: 1.5, ..Default::default() };
        assert_eq!(p.validate().map_err(|e| e.field), Err("corridor_probability"));
        let p: ApartmentParams = ron::from_str("(max_side_m: 12.0)").expect("partial RON uses defaults");
        assert_eq!((p.max_side_m, p.min_side_m), (12.0, 6.0));
        assert!(ron::from_str::<ApartmentParams>("(max_sides_m: 12.0)").is_err(), "unknown fields rejected");
    }

    #[test]
    fn cell_params_clamp_nonsense_instead_of_panicking() {
        let p = ApartmentParams {
            resolution_m: f32::NAN,
            min_side_m: 50.0,
            max_side_m: 10.0,
            door_max_m: 0.1,
            min_rooms: 0,
            max_rooms: 0,
            ..Default::default()
        };
        let c = CellParams::new(&p);
        assert_eq!(c.resolution_m, 0.05, "NaN resolution falls back to the default");
        assert!(c.min_side_m <= c.max_side_m, "side range must be ordered");
        assert!(c.door_max >= c.door_min && c.min_rooms >= 1 && c.max_rooms >= c.min_rooms);
        assert_eq!((c.wall_lo, c.wall_hi), (1, 1), "0.1 m wall = two 5 cm cells centred on the line");
    }
}
