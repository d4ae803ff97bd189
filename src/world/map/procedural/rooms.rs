//! The floor plan: outline (rectangle or L), rooms by recursive binary space partitioning with
//! random split positions, an optional corridor, and doors or wide openings joining every room.

use super::params::CellParams;
use super::rect::CellRect;
use rand::Rng;

/// What a room is used for; furniture follows from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum RoomRole {
    Corridor,
    Living,
    Kitchen,
    Other,
}

/// One room, its rectangle running wall centre to wall centre.
#[derive(Clone, Debug)]
pub(super) struct Room {
    pub rect: CellRect,
    pub role: RoomRole,
}

/// A gap cut into a wall between two rooms: a door or an open-plan opening.
#[derive(Clone, Debug)]
pub(super) struct Opening {
    /// Wall cells turned free.
    pub carved: CellRect,
    /// The gap plus the floor in front of it on both sides, which furniture must leave clear.
    pub keep_clear: CellRect,
    pub rooms: (usize, usize),
}

/// A whole apartment before furniture, in the cells of the final map.
#[derive(Clone, Debug)]
pub(super) struct FloorPlan {
    pub width: usize,
    pub height: usize,
    pub rooms: Vec<Room>,
    pub openings: Vec<Opening>,
}

/// Where two rooms share a wall: the grid line `at` (an x if `vertical`), cells `s0..s1` along it.
#[derive(Clone, Copy, Debug)]
struct SharedWall {
    a: usize,
    b: usize,
    vertical: bool,
    at: i32,
    s0: i32,
    s1: i32,
}

/// Draws a floor plan, or `None` when its rooms cannot all be joined by doors (the caller then
/// tries the next stream). `simple` asks for one rectangular room, which always succeeds.
pub(super) fn plan(p: &CellParams, rng: &mut impl Rng, simple: bool) -> Option<FloorPlan> {
    let (w, h) = draw_size(p, rng);
    let whole = CellRect::new(p.margin, p.margin, p.margin + w, p.margin + h);
    let mut regions =
        if !simple && rng.random_bool(p.l_shape_probability) { l_shape(whole, p, rng) } else { vec![whole] };
    let floor_m2 = p.area_m2(regions.iter().map(CellRect::area).sum());
    let target = if simple { 1 } else { room_count(floor_m2, p, rng) };

    let mut rooms = Vec::new();
    let corridor = !simple && rng.random_bool(p.corridor_probability);
    if corridor {
        let k = (0..regions.len()).max_by_key(|&k| regions[k].area()).unwrap_or(0);
        if let Some((hall, sides)) = corridor_layout(regions[k], p, rng) {
            rooms.push(Room { rect: hall, role: RoomRole::Corridor });
            regions.swap_remove(k);
            regions.extend(sides);
        }
    }
    let total: i64 = regions.iter().map(CellRect::area).sum();
    for region in regions {
        let share = (target as f64 * region.area() as f64 / total.max(1) as f64).round() as usize;
        let leaves = partition(region, share.max(1), p.min_room, rng);
        rooms.extend(leaves.into_iter().map(|rect| Room { rect, role: RoomRole::Other }));
    }

    let open_plan = !rooms.iter().any(|r| r.role == RoomRole::Corridor);
    let openings = connect(&mut rooms, open_plan, p, rng)?;
    let side = |n: i32| (n + 2 * p.margin) as usize;
    Some(FloorPlan { width: side(w), height: side(h), rooms, openings })
}

/// Bounding-box sides in cells: uniform in the side range, aspect ratio bounded.
fn draw_size(p: &CellParams, rng: &mut impl Rng) -> (i32, i32) {
    let (lo, hi) = (p.min_side_m, p.max_side_m);
    let a = rng.random_range(lo..=hi);
    let b = rng.random_range(lo.max(a / p.max_aspect)..=hi.min(a * p.max_aspect));
    let (w, h) = if rng.random_bool(0.5) { (a, b) } else { (b, a) };
    (p.cells(w), p.cells(h))
}

fn room_count(floor_m2: f32, p: &CellParams, rng: &mut impl Rng) -> usize {
    let per_room = p.mean_room_area_m2 * rng.random_range(0.7..=1.3);
    ((floor_m2 / per_room).round() as usize).clamp(p.min_rooms, p.max_rooms)
}

/// Cuts a corner off `whole` and returns the L as two rectangles, or `whole` if it is too small.
fn l_shape(whole: CellRect, p: &CellParams, rng: &mut impl Rng) -> Vec<CellRect> {
    let (w, h) = (whole.width(), whole.height());
    let cut_range = |n: i32| (p.min_room.max(n * 3 / 10), (n - p.min_room).min(n * 11 / 20));
    let ((cw_lo, cw_hi), (ch_lo, ch_hi)) = (cut_range(w), cut_range(h));
    if cw_lo > cw_hi || ch_lo > ch_hi {
        return vec![whole];
    }
    let (cw, ch) = (rng.random_range(cw_lo..=cw_hi), rng.random_range(ch_lo..=ch_hi));
    let (x0, y0, x1, y1) = (whole.x0, whole.y0, whole.x1, whole.y1);
    // Cut the top-right corner, splitting the L either across or along, then mirror.
    let parts = if rng.random_bool(0.5) {
        [CellRect::new(x0, y0, x1, y1 - ch), CellRect::new(x0, y1 - ch, x1 - cw, y1)]
    } else {
        [CellRect::new(x0, y0, x1 - cw, y1), CellRect::new(x1 - cw, y0, x1, y1 - ch)]
    };
    let (flip_x, flip_y) = (rng.random_bool(0.5), rng.random_bool(0.5));
    parts
        .into_iter()
        .map(|r| {
            let (rx0, rx1) = if flip_x { (x0 + x1 - r.x1, x0 + x1 - r.x0) } else { (r.x0, r.x1) };
            let (ry0, ry1) = if flip_y { (y0 + y1 - r.y1, y0 + y1 - r.y0) } else { (r.y0, r.y1) };
            CellRect::new(rx0, ry0, rx1, ry1)
        })
        .collect()
}

/// A hallway along the long axis of `r` with room strips on both sides and, usually, an end
/// region beyond it. Returns (corridor, other regions), or `None` if `r` is too narrow.
fn corridor_layout(r: CellRect, p: &CellParams, rng: &mut impl Rng) -> Option<(CellRect, Vec<CellRect>)> {
    let transpose = r.height() > r.width();
    let (long, short) = if transpose { (r.height(), r.width()) } else { (r.width(), r.height()) };
    let cw = rng.random_range(p.corridor_min..=p.corridor_max);
    if short < 2 * p.min_room + cw || long < 2 * p.min_room {
        return None;
    }
    let side1 = rng.random_range(p.min_room..=short - p.min_room - cw);
    let shortest_hall = (long * 11 / 20).max(p.min_room);
    let hall = if long - p.min_room >= shortest_hall && rng.random_bool(0.75) {
        rng.random_range(shortest_hall..=long - p.min_room)
    } else {
        long
    };
    let flip = rng.random_bool(0.5);
    // Rectangles in (along, across) coordinates relative to r, then mapped into the grid.
    let to_grid = |u0: i32, v0: i32, u1: i32, v1: i32| {
        let (u0, u1) = if flip { (long - u1, long - u0) } else { (u0, u1) };
        if transpose {
            CellRect::new(r.x0 + v0, r.y0 + u0, r.x0 + v1, r.y0 + u1)
        } else {
            CellRect::new(r.x0 + u0, r.y0 + v0, r.x0 + u1, r.y0 + v1)
        }
    };
    let corridor = to_grid(0, side1, hall, side1 + cw);
    let mut others = vec![to_grid(0, 0, hall, side1), to_grid(0, side1 + cw, hall, short)];
    if hall < long {
        others.push(to_grid(hall, 0, long, short));
    }
    Some((corridor, others))
}

/// Recursive binary space partitioning of `region` into up to `count` rooms: repeatedly splits
/// a leaf (chosen with probability ∝ area) at a uniform position, mostly across its long side.
fn partition(region: CellRect, count: usize, min_side: i32, rng: &mut impl Rng) -> Vec<CellRect> {
    let mut leaves = vec![region];
    while leaves.len() < count {
        let splittable = |r: &CellRect| r.width() >= 2 * min_side || r.height() >= 2 * min_side;
        let total: i64 = leaves.iter().filter(|r| splittable(r)).map(CellRect::area).sum();
        if total == 0 {
            break;
        }
        let mut pick = rng.random_range(0..total);
        let k = leaves
            .iter()
            .position(|r| {
                let a = if splittable(r) { r.area() } else { 0 };
                if pick < a {
                    return true;
                }
                pick -= a;
                false
            })
            .unwrap_or(0);
        let r = leaves.swap_remove(k);
        let (can_x, can_y) = (r.width() >= 2 * min_side, r.height() >= 2 * min_side);
        let across_x = match (can_x, can_y) {
            (true, false) => true,
            (false, true) => false,
            _ => (r.width() >= r.height()) == rng.random_bool(0.85),
        };
        if across_x {
            let cut = r.x0 + rng.random_range(min_side..=r.width() - min_side);
            leaves.push(CellRect::new(r.x0, r.y0, cut, r.y1));
            leaves.push(CellRect::new(cut, r.y0, r.x1, r.y1));
        } else {
            let cut = r.y0 + rng.random_range(min_side..=r.height() - min_side);
            leaves.push(CellRect::new(r.x0, r.y0, r.x1, cut));
            leaves.push(CellRect::new(r.x0, cut, r.x1, r.y1));
        }
    }
    leaves
}

/// Every pair of rooms sharing enough wall for a door.
fn shared_walls(rooms: &[Room], p: &CellParams) -> Vec<SharedWall> {
    let needed = p.door_min + p.wall_lo + p.wall_hi + 2 * p.door_corner;
    let mut walls = Vec::new();
    for a in 0..rooms.len() {
        for b in a + 1..rooms.len() {
            let (ra, rb) = (rooms[a].rect, rooms[b].rect);
            let line = if ra.x1 == rb.x0 || rb.x1 == ra.x0 {
                let at = if ra.x1 == rb.x0 { ra.x1 } else { ra.x0 };
                Some((true, at, ra.y0.max(rb.y0), ra.y1.min(rb.y1)))
            } else if ra.y1 == rb.y0 || rb.y1 == ra.y0 {
                let at = if ra.y1 == rb.y0 { ra.y1 } else { ra.y0 };
                Some((false, at, ra.x0.max(rb.x0), ra.x1.min(rb.x1)))
            } else {
                None
            };
            if let Some((vertical, at, s0, s1)) = line
                && s1 - s0 >= needed
            {
                walls.push(SharedWall { a, b, vertical, at, s0, s1 });
            }
        }
    }
    walls
}

/// Cuts openings so that every room is reachable: in an open plan the largest room first opens
/// widely onto one or two neighbours; then a random spanning tree of doors (rooms off a corridor
/// preferring a door onto it), then extra doors. Sets room roles. `None` if the rooms cannot
/// all be joined.
fn connect(rooms: &mut [Room], open_plan: bool, p: &CellParams, rng: &mut impl Rng) -> Option<Vec<Opening>> {
    let mut walls = shared_walls(rooms, p);
    let mut parent: Vec<usize> = (0..rooms.len()).collect();
    let mut openings = Vec::new();
    let hub = (0..rooms.len())
        .filter(|&k| rooms[k].role != RoomRole::Corridor)
        .max_by_key(|&k| rooms[k].rect.area());
    if let Some(hub) = hub {
        rooms[hub].role = RoomRole::Living;
    }
    if open_plan && let Some(hub) = hub {
        let wide = rng.random_range(1..=2usize);
        let mut merged = 0;
        let mut k = 0;
        while k < walls.len() && merged < wide {
            let wall = walls[k];
            if (wall.a == hub || wall.b == hub) && rng.random_bool(0.7) {
                let other = if wall.a == hub { wall.b } else { wall.a };
                if merged == 0 {
                    rooms[other].role = RoomRole::Kitchen;
                }
                union(&mut parent, wall.a, wall.b);
                openings.push(wide_opening(&wall, p, rng));
                walls.swap_remove(k);
                merged += 1;
            } else {
                k += 1;
            }
        }
    }
    let mut weighted: Vec<(f32, SharedWall)> = walls
        .into_iter()
        .map(|wall| {
            let to_hall =
                rooms[wall.a].role == RoomRole::Corridor || rooms[wall.b].role == RoomRole::Corridor;
            (if to_hall { 0.0 } else { 1.0 } + rng.random::<f32>(), wall)
        })
        .collect();
    weighted.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut spare = Vec::new();
    for (_, wall) in weighted {
        if union(&mut parent, wall.a, wall.b) {
            openings.push(door(&wall, p, rng));
        } else {
            spare.push(wall);
        }
    }
    for wall in spare {
        if rng.random_bool(p.extra_door_probability) {
            openings.push(door(&wall, p, rng));
        }
    }
    let root = find(&mut parent, 0);
    let joined = (0..rooms.len()).all(|k| find(&mut parent, k) == root);
    if joined && let Some(k) = pick_kitchen(rooms, p, rng) {
        rooms[k].role = RoomRole::Kitchen;
    }
    joined.then_some(openings)
}

/// Without an open-plan kitchen, a medium room (6–16 m²) becomes the kitchen.
fn pick_kitchen(rooms: &[Room], p: &CellParams, rng: &mut impl Rng) -> Option<usize> {
    if rooms.iter().any(|r| r.role == RoomRole::Kitchen) {
        return None;
    }
    let medium: Vec<usize> = (0..rooms.len())
        .filter(|&k| rooms[k].role == RoomRole::Other)
        .filter(|&k| (6.0..=16.0).contains(&p.area_m2(rooms[k].rect.area())))
        .collect();
    (!medium.is_empty()).then(|| medium[rng.random_range(0..medium.len())])
}

/// A door of random width at a random place along a shared wall, clear of both corners.
fn door(wall: &SharedWall, p: &CellParams, rng: &mut impl Rng) -> Opening {
    let (lo, hi) = (wall.s0 + p.wall_hi + p.door_corner, wall.s1 - p.wall_lo - p.door_corner);
    let width = rng.random_range(p.door_min..=p.door_max.min(hi - lo).max(p.door_min));
    let start = rng.random_range(lo..=(hi - width).max(lo));
    gap(wall, start, start + width, p)
}

/// Most of a shared wall removed: the whole wall, or all but short stubs at both ends.
fn wide_opening(wall: &SharedWall, p: &CellParams, rng: &mut impl Rng) -> Opening {
    let (mut lo, mut hi) = (wall.s0 + p.wall_hi, wall.s1 - p.wall_lo);
    let stub = rng.random_range(p.cells(0.3)..=p.cells(0.8));
    if rng.random_bool(0.5) && hi - lo - 2 * stub >= p.door_max * 3 / 2 {
        lo += stub;
        hi -= stub;
    }
    gap(wall, lo, hi, p)
}

fn gap(wall: &SharedWall, start: i32, end: i32, p: &CellParams) -> Opening {
    let (band0, band1) = (wall.at - p.wall_lo, wall.at + p.wall_hi);
    let (keep0, keep1) = (band0 - p.keep_depth, band1 + p.keep_depth);
    let (side0, side1) = (start - p.keep_side, end + p.keep_side);
    let (carved, keep_clear) = if wall.vertical {
        (CellRect::new(band0, start, band1, end), CellRect::new(keep0, side0, keep1, side1))
    } else {
        (CellRect::new(start, band0, end, band1), CellRect::new(side0, keep0, side1, keep1))
    };
    Opening { carved, keep_clear, rooms: (wall.a, wall.b) }
}

fn find(parent: &mut [usize], mut k: usize) -> usize {
    while parent[k] != k {
        parent[k] = parent[parent[k]];
        k = parent[k];
    }
    k
}

/// Joins the sets of `a` and `b`; false if they were already one.
fn union(parent: &mut [usize], a: usize, b: usize) -> bool {
    let (ra, rb) = (find(parent, a), find(parent, b));
    parent[ra] = rb;
    ra != rb
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::map::procedural::ApartmentParams;
    use crate::world::rng::stream;

    #[test]
    fn partition_tiles_the_region_with_rooms_no_thinner_than_the_minimum() {
        let region = CellRect::new(10, 10, 310, 210);
        let rooms = partition(region, 7, 44, &mut stream(&[3]));
        assert!(rooms.len() >= 4, "a 15 m × 10 m region holds several 2.2 m rooms, got {}", rooms.len());
        assert_eq!(
            rooms.iter().map(CellRect::area).sum::<i64>(),
            region.area(),
            "rooms must tile the region"
        );
        for (k, r) in rooms.iter().enumerate() {
            assert!(r.width() >= 44 && r.height() >= 44, "room {r:?} thinner than the minimum");
            assert!(rooms[k + 1..].iter().all(|o| !o.intersects(r)), "rooms must not overlap");
        }
    }

    #[test]
    fn every_plan_connects_all_rooms_through_its_openings() {
        let p = CellParams::new(&ApartmentParams::default());
        for seed in 0..40u64 {
            let Some(plan) = plan(&p, &mut stream(&[seed]), false) else { continue };
            let mut parent: Vec<usize> = (0..plan.rooms.len()).collect();
            for o in &plan.openings {
                union(&mut parent, o.rooms.0, o.rooms.1);
                assert!(
                    o.carved.width().min(o.carved.height()) == p.wall_lo + p.wall_hi,
                    "gap spans the wall"
                );
                assert!(
                    o.carved.width().max(o.carved.height()) >= p.door_min,
                    "opening narrower than a door"
                );
            }
            let root = find(&mut parent, 0);
            assert!(
                (0..plan.rooms.len()).all(|k| find(&mut parent, k) == root),
                "seed {seed}: a room is cut off"
            );
        }
    }

    #[test]
    fn corridor_layout_puts_the_hall_between_two_room_strips() {
        let p = CellParams::new(&ApartmentParams::default());
        let r = CellRect::new(0, 0, 300, 160);
        let (hall, others) = corridor_layout(r, &p, &mut stream(&[1])).expect("8 m wide fits a corridor");
        assert!((p.corridor_min..=p.corridor_max).contains(&hall.height()), "hall width {hall:?}");
        let covered = hall.area() + others.iter().map(CellRect::area).sum::<i64>();
        assert_eq!(covered, r.area(), "hall and regions must tile the rectangle");
        assert!(others.iter().filter(|o| o.width() == hall.width() && o.x0 == hall.x0).count() == 2);
        assert!(corridor_layout(CellRect::new(0, 0, 300, 100), &p, &mut stream(&[1])).is_none());
    }
}
