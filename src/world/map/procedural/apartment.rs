//! One apartment from one seed: floor plan, then furniture, drawn onto an occupancy grid, then
//! roughened to look like a SLAM map.

use super::furniture::{Piece, furnish};
use super::params::{ApartmentParams, CellParams};
use super::realism::roughen;
use super::rect::CellRect;
use super::rooms::{FloorPlan, plan};
use crate::world::map::{Cell, OccupancyMap};
use crate::world::rng::stream;

/// Stream keys of the two stages, so furniture draws never shift the floor plan (the realism
/// layer has its own).
const STAGE_PLAN: u64 = 0x706c_616e;
const STAGE_FURNITURE: u64 = 0x6675_726e;
/// Floor plans tried before falling back to a single room (in practice one or two suffice).
const MAX_ATTEMPTS: u64 = 64;

/// The apartment of `seed`: outside Unknown, walls Occupied, floor Free; origin (0, 0), the
/// apartment inset by `margin_m`. The same seed and params always give the same map. With
/// `params.realism` on (the default) walls are uneven and furniture is drawn as a scanner sees
/// it, parts of it unknown; off, the map is the clean plan as before the layer existed.
pub fn generate_apartment(seed: u64, params: &ApartmentParams) -> OccupancyMap {
    let p = CellParams::new(params);
    let floor_plan = (0..MAX_ATTEMPTS)
        .find_map(|attempt| plan(&p, &mut stream(&[seed, STAGE_PLAN, attempt]), false))
        .or_else(|| plan(&p, &mut stream(&[seed, STAGE_PLAN, MAX_ATTEMPTS]), true))
        .expect("a single-room plan needs no doors and always succeeds");
    let pieces = furnish(&floor_plan, &p, &mut stream(&[seed, STAGE_FURNITURE]));
    let clean = draw(&floor_plan, &pieces, &p);
    roughen(clean, &floor_plan, &pieces, &p, &params.realism, seed)
}

fn draw(plan: &FloorPlan, pieces: &[Piece], p: &CellParams) -> OccupancyMap {
    let mut map = OccupancyMap::filled(plan.width, plan.height, p.resolution_m, Cell::Unknown);
    for room in &plan.rooms {
        fill(&mut map, &room.rect, Cell::Free);
    }
    let (lo, hi) = (p.wall_lo, p.wall_hi);
    for room in &plan.rooms {
        let r = room.rect;
        for band in [
            CellRect::new(r.x0 - lo, r.y0 - lo, r.x0 + hi, r.y1 + hi),
            CellRect::new(r.x1 - lo, r.y0 - lo, r.x1 + hi, r.y1 + hi),
            CellRect::new(r.x0 - lo, r.y0 - lo, r.x1 + hi, r.y0 + hi),
            CellRect::new(r.x0 - lo, r.y1 - lo, r.x1 + hi, r.y1 + hi),
        ] {
            fill(&mut map, &band, Cell::Occupied);
        }
    }
    for opening in &plan.openings {
        fill(&mut map, &opening.carved, Cell::Free);
    }
    for piece in pieces {
        if piece.round {
            disc(&mut map, &piece.rect);
        } else {
            fill(&mut map, &piece.rect, Cell::Occupied);
        }
    }
    map
}

/// Sets every cell of `r` that lies on the map.
fn fill(map: &mut OccupancyMap, r: &CellRect, cell: Cell) {
    let clip = |v: i32, n: usize| v.clamp(0, n as i32) as usize;
    for j in clip(r.y0, map.height)..clip(r.y1, map.height) {
        for i in clip(r.x0, map.width)..clip(r.x1, map.width) {
            map.set(i, j, cell);
        }
    }
}

/// Occupies the cells whose centres lie in the disc inscribed in the square `r`.
fn disc(map: &mut OccupancyMap, r: &CellRect) {
    let (cx, cy) = ((r.x0 + r.x1) as f32 / 2.0, (r.y0 + r.y1) as f32 / 2.0);
    let radius = r.width() as f32 / 2.0;
    for j in r.y0.max(0)..r.y1.min(map.height as i32) {
        for i in r.x0.max(0)..r.x1.min(map.width as i32) {
            if (i as f32 + 0.5 - cx).hypot(j as f32 + 0.5 - cy) <= radius {
                map.set(i as usize, j as usize, Cell::Occupied);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::map::TraversableMap;
    use crate::world::map::procedural::{RealismParams, SEEN_SEEDS, UNSEEN_SEEDS};
    use crate::world::robot::RobotParams;
    use std::collections::VecDeque;

    /// Seeds from both splits.
    fn seeds(n: u64) -> impl Iterator<Item = u64> {
        (SEEN_SEEDS.start..SEEN_SEEDS.start + n / 2).chain(UNSEEN_SEEDS.start..UNSEEN_SEEDS.start + n - n / 2)
    }

    /// Cells where a disc of `radius_m` centred on the cell centre overlaps no non-free cell.
    fn eroded(map: &OccupancyMap, radius_m: f32) -> Vec<bool> {
        let r = radius_m / map.resolution_m;
        let reach = r.ceil() as i32 + 1;
        let offsets: Vec<(i32, i32)> = (-reach..=reach)
            .flat_map(|dj| (-reach..=reach).map(move |di| (di, dj)))
            .filter(|&(di, dj)| {
                let near = |d: i32| (d.abs() as f32 - 0.5).max(0.0);
                near(di).hypot(near(dj)) < r
            })
            .collect();
        let (w, h) = (map.width as i32, map.height as i32);
        let mut out = vec![false; map.cells.len()];
        for j in 0..h {
            for i in 0..w {
                out[(j * w + i) as usize] = offsets.iter().all(|&(di, dj)| {
                    let (x, y) = (i + di, j + dj);
                    x >= 0 && y >= 0 && x < w && y < h && map.get(x as usize, y as usize) == Cell::Free
                });
            }
        }
        out
    }

    /// Sizes of the 4-connected components of `mask`, largest first.
    fn components(mask: &[bool], width: usize) -> Vec<usize> {
        let mut seen = vec![false; mask.len()];
        let mut sizes = Vec::new();
        let mut queue = VecDeque::new();
        for start in 0..mask.len() {
            if !mask[start] || seen[start] {
                continue;
            }
            seen[start] = true;
            queue.push_back(start);
            let mut size = 0;
            while let Some(k) = queue.pop_front() {
                size += 1;
                let (i, j) = (k % width, k / width);
                let mut visit = |n: usize| {
                    if mask[n] && !seen[n] {
                        seen[n] = true;
                        queue.push_back(n);
                    }
                };
                if i > 0 {
                    visit(k - 1);
                }
                if i + 1 < width {
                    visit(k + 1);
                }
                if j > 0 {
                    visit(k - width);
                }
                if k + width < mask.len() {
                    visit(k + width);
                }
            }
            sizes.push(size);
        }
        sizes.sort_unstable_by(|a, b| b.cmp(a));
        sizes
    }

    /// Extent of the non-unknown cells, metres, and the unknown margin on each side, cells.
    fn footprint(map: &OccupancyMap) -> ((f32, f32), [usize; 4]) {
        let (mut i0, mut j0, mut i1, mut j1) = (usize::MAX, usize::MAX, 0, 0);
        for j in 0..map.height {
            for i in 0..map.width {
                if map.get(i, j) != Cell::Unknown {
                    (i0, j0, i1, j1) = (i0.min(i), j0.min(j), i1.max(i + 1), j1.max(j + 1));
                }
            }
        }
        let res = map.resolution_m;
        (((i1 - i0) as f32 * res, (j1 - j0) as f32 * res), [i0, j0, map.width - i1, map.height - j1])
    }

    #[test]
    fn same_seed_same_map_and_different_seeds_differ() {
        let p = ApartmentParams::default();
        for seed in [0, 17, 1_000_000] {
            assert_eq!(
                generate_apartment(seed, &p),
                generate_apartment(seed, &p),
                "seed {seed} not reproducible"
            );
        }
        let maps: Vec<OccupancyMap> = (0..6).map(|s| generate_apartment(s, &p)).collect();
        for a in 0..maps.len() {
            for b in a + 1..maps.len() {
                assert_ne!(maps[a], maps[b], "seeds {a} and {b} gave the same apartment");
            }
        }
    }

    #[test]
    fn apartments_stay_within_the_size_bounds_with_an_unknown_margin() {
        let p = ApartmentParams::default();
        let wall = p.wall_thickness_m;
        for seed in seeds(50) {
            let map = generate_apartment(seed, &p);
            assert_eq!(map.origin, crate::world::Pose2::default(), "origin must be (0, 0, 0)");
            let ((w, h), margins) = footprint(&map);
            for side in [w, h] {
                assert!(
                    side >= p.min_side_m - 1e-3 && side <= p.max_side_m + wall + 1e-3,
                    "seed {seed}: side {side} m outside [{}, {}] m",
                    p.min_side_m,
                    p.max_side_m + wall
                );
            }
            let expected = ((p.margin_m - wall / 2.0) / p.resolution_m).round() as usize;
            assert!(
                margins.iter().all(|&m| m == expected),
                "seed {seed}: margins {margins:?}, want {expected}"
            );
        }
    }

    #[test]
    fn robot_reaches_almost_all_free_space() {
        let p = ApartmentParams::default();
        let radius = RobotParams::default().radius_m;
        for seed in seeds(50) {
            let map = generate_apartment(seed, &p);
            let mask = eroded(&map, radius);
            let sizes = components(&mask, map.width);
            let total: usize = sizes.iter().sum();
            assert!(total > 0, "seed {seed}: no room for the robot at all");
            let share = sizes[0] as f32 / total as f32;
            assert!(
                share >= 0.9,
                "seed {seed}: largest reachable region holds only {:.1} % of it",
                100.0 * share
            );
        }
    }

    #[test]
    fn every_room_is_reachable_by_the_robot() {
        let p = ApartmentParams::default();
        let c = CellParams::new(&p);
        let radius = RobotParams::default().radius_m;
        for seed in seeds(20) {
            let floor_plan = (0..MAX_ATTEMPTS)
                .find_map(|attempt| plan(&c, &mut stream(&[seed, STAGE_PLAN, attempt]), false))
                .expect("a plan within the attempts");
            let map = generate_apartment(seed, &p);
            let mask = eroded(&map, radius);
            // Keep only the component of the first room's first reachable cell.
            let inner0 = floor_plan.rooms[0].rect.inset(c.wall_hi, c.wall_lo);
            let start = (inner0.y0..inner0.y1)
                .flat_map(|j| (inner0.x0..inner0.x1).map(move |i| (j as usize) * map.width + i as usize))
                .find(|&k| mask[k])
                .expect("room 0 has space for the robot");
            let mut reach = vec![false; mask.len()];
            let mut queue = VecDeque::from([start]);
            reach[start] = true;
            while let Some(k) = queue.pop_front() {
                for n in [k - 1, k + 1, k - map.width, k + map.width] {
                    if mask[n] && !reach[n] {
                        reach[n] = true;
                        queue.push_back(n);
                    }
                }
            }
            for (r, room) in floor_plan.rooms.iter().enumerate() {
                let inner = room.rect.inset(c.wall_hi, c.wall_lo);
                let inside = (inner.y0..inner.y1)
                    .any(|j| (inner.x0..inner.x1).any(|i| reach[j as usize * map.width + i as usize]));
                assert!(inside, "seed {seed}: room {r} ({:?}) unreachable", room.role);
            }
        }
    }

    #[test]
    fn occupied_fraction_is_plausible_and_furniture_is_present() {
        let p = ApartmentParams::default();
        let empty = ApartmentParams { furniture_per_m2: 0.0, pillar_probability: 0.0, ..Default::default() };
        for seed in seeds(30) {
            let (free, occupied, _) = generate_apartment(seed, &p).counts();
            let share = occupied as f32 / (free + occupied) as f32;
            assert!(
                (0.04..=0.35).contains(&share),
                "seed {seed}: occupied share {share:.3} of the apartment"
            );
            let (_, bare, _) = generate_apartment(seed, &empty).counts();
            assert!(bare <= occupied, "seed {seed}: furniture can only add obstacles");
        }
        let furnished =
            seeds(30).filter(|&s| generate_apartment(s, &p) != generate_apartment(s, &empty)).count();
        assert!(furnished >= 27, "only {furnished}/30 apartments got any furniture");
    }

    #[test]
    fn floor_plans_never_need_the_single_room_fallback() {
        let c = CellParams::new(&ApartmentParams::default());
        for seed in seeds(200) {
            let first = (0..MAX_ATTEMPTS)
                .position(|a| plan(&c, &mut stream(&[seed, STAGE_PLAN, a]), false).is_some());
            assert!(first.is_some_and(|a| a < 8), "seed {seed}: floor plan needed attempt {first:?}");
        }
    }

    /// The floor plan `generate_apartment` draws for `seed`.
    fn plan_of(seed: u64, params: &ApartmentParams) -> FloorPlan {
        let c = CellParams::new(params);
        (0..MAX_ATTEMPTS)
            .find_map(|attempt| plan(&c, &mut stream(&[seed, STAGE_PLAN, attempt]), false))
            .expect("a plan within the attempts")
    }

    /// FNV-1a over the cells, bottom row first (free 0, occupied 1, unknown 2).
    fn fingerprint(map: &OccupancyMap) -> u64 {
        map.cells.iter().fold(0xcbf2_9ce4_8422_2325, |h, &c| (h ^ c as u64).wrapping_mul(0x100_0000_01b3))
    }

    #[test]
    fn realism_off_reproduces_the_maps_made_before_the_layer() {
        let off = ApartmentParams {
            realism: RealismParams { enabled: false, ..Default::default() },
            ..Default::default()
        };
        // Fingerprints of `apfn map export --procedural SEED` from a build before the layer existed.
        for (seed, before) in
            [(0, 0x649f_4a75_ec32_2e06), (17, 0xc100_fee6_0a1b_8c61), (1_000_000, 0x2938_cc50_9e20_ceaa)]
        {
            assert_eq!(
                fingerprint(&generate_apartment(seed, &off)),
                before,
                "seed {seed} changed with realism off"
            );
        }
        let zero_rates = ApartmentParams { realism: RealismParams::none(), ..Default::default() };
        for seed in seeds(6) {
            assert_eq!(generate_apartment(seed, &zero_rates), generate_apartment(seed, &off), "seed {seed}");
        }
    }

    #[test]
    fn realism_is_reproducible_and_changes_the_map() {
        let realistic = ApartmentParams { realism: RealismParams::default(), ..ApartmentParams::default() };
        for params in [realistic, ApartmentParams::paper_size()] {
            let clean = ApartmentParams {
                realism: RealismParams { enabled: false, ..Default::default() },
                ..params.clone()
            };
            for seed in [3, 1_000_003] {
                let map = generate_apartment(seed, &params);
                assert_eq!(fingerprint(&map), fingerprint(&generate_apartment(seed, &params)), "seed {seed}");
                assert_ne!(map, generate_apartment(seed, &clean), "seed {seed}: realism changed nothing");
            }
        }
    }

    #[test]
    fn outside_the_outer_walls_is_unknown() {
        for params in [ApartmentParams::default(), ApartmentParams::paper_size()] {
            let c = CellParams::new(&params);
            for seed in seeds(10) {
                let map = generate_apartment(seed, &params);
                let walled: Vec<CellRect> = plan_of(seed, &params)
                    .rooms
                    .iter()
                    .map(|room| room.rect)
                    .map(|r| {
                        CellRect::new(r.x0 - c.wall_lo, r.y0 - c.wall_lo, r.x1 + c.wall_hi, r.y1 + c.wall_hi)
                    })
                    .collect();
                for j in 0..map.height as i32 {
                    for i in 0..map.width as i32 {
                        let inside = walled.iter().any(|r| r.contains(&CellRect::new(i, j, i + 1, j + 1)));
                        assert!(
                            inside || map.get(i as usize, j as usize) == Cell::Unknown,
                            "seed {seed}: cell ({i}, {j}) outside the walls is {:?}",
                            map.get(i as usize, j as usize)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn traversable_space_is_one_component_of_sane_area_in_both_presets() {
        let radius = RobotParams::default().radius_m;
        for params in [ApartmentParams::default(), ApartmentParams::paper_size()] {
            let c = CellParams::new(&params);
            for seed in seeds(20) {
                let map = generate_apartment(seed, &params);
                let sizes = components(&eroded(&map, radius), map.width);
                let total: usize = sizes.iter().sum();
                assert!(
                    sizes[0] as f32 >= 0.9 * total as f32,
                    "seed {seed}: largest region holds {} of {total} cells the robot fits in",
                    sizes[0]
                );
                let floor: i64 = plan_of(seed, &params)
                    .rooms
                    .iter()
                    .map(|r| r.rect.inset(c.wall_hi, c.wall_lo).area())
                    .sum();
                let trav = TraversableMap::build(&map, radius).expect("room for the robot");
                let share = trav.cells.len() as f32 / floor as f32;
                assert!(
                    (0.3..=0.95).contains(&share),
                    "seed {seed}: traversable share {share:.2} of the floor"
                );
            }
        }
    }

    #[test]
    fn paper_size_keeps_the_traversable_bounding_box_within_10_m() {
        let p = ApartmentParams::paper_size();
        assert_eq!(p.validate(), Ok(()));
        let radius = RobotParams::default().radius_m;
        for seed in seeds(30) {
            let map = generate_apartment(seed, &p);
            let ((w, h), _) = footprint(&map);
            assert!(w >= p.min_side_m - 1e-3 && w.max(h) <= 10.1 + 1e-3, "seed {seed}: {w} × {h} m");
            let trav = TraversableMap::build(&map, radius).expect("room for the robot");
            let span = |axis: fn(&(u32, u32)) -> u32| {
                let (lo, hi) =
                    trav.cells.iter().map(axis).fold((u32::MAX, 0), |(a, b), v| (a.min(v), b.max(v)));
                (hi + 1 - lo) as f32 * p.resolution_m
            };
            let (tw, th) = (span(|c| c.0), span(|c| c.1));
            assert!(tw <= 10.0 && th <= 10.0, "seed {seed}: traversable box {tw} × {th} m");
        }
        let c = CellParams::new(&p);
        for seed in seeds(100) {
            let first = (0..MAX_ATTEMPTS)
                .position(|a| plan(&c, &mut stream(&[seed, STAGE_PLAN, a]), false).is_some());
            assert!(first.is_some_and(|a| a < 8), "seed {seed}: floor plan needed attempt {first:?}");
        }
    }

    #[test]
    fn other_resolutions_scale_the_grid() {
        let coarse = ApartmentParams { resolution_m: 0.1, ..Default::default() };
        let map = generate_apartment(3, &coarse);
        let ((w, h), _) = footprint(&map);
        assert_eq!(map.resolution_m, 0.1);
        assert!((6.0..=20.2).contains(&w) && (6.0..=20.2).contains(&h), "{w} × {h} m at 0.1 m cells");
    }
}
