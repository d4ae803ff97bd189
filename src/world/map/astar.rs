//! A* on the traversable map: 8-connected, octile heuristic, no cutting corners past
//! non-traversable cells. Flat arrays and a binary heap, so a 1006 × 1674 map plans in well under
//! a second.

use crate::world::map::layers::TraversableMap;
use crate::world::map::occupancy::OccupancyMap;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f32::consts::SQRT_2;

/// Shortest 8-connected path between the cells containing `start` and `goal` (world metres),
/// as world coordinates of cell centres from start to goal (both included). `None` when either
/// point is off the map or not traversable, when no path exists, or when `trav` was not built
/// from a grid of `map`'s size.
pub fn plan_path(
    trav: &TraversableMap,
    map: &OccupancyMap,
    start: (f32, f32),
    goal: (f32, f32),
) -> Option<Vec<(f32, f32)>> {
    if (trav.width, trav.height) != (map.width, map.height) {
        return None;
    }
    let snap = |(x, y): (f32, f32)| map.cell_at(x, y).filter(|&(i, j)| trav.is_traversable(i, j));
    let cells = plan_cells(trav, snap(start)?, snap(goal)?)?;
    Some(cells.into_iter().map(|(i, j)| map.cell_center(i, j)).collect())
}

/// The A* kernel on cell indices: the cells from `start` to `goal`, or `None` when either is not
/// traversable or no path exists.
pub fn plan_cells(
    trav: &TraversableMap,
    start: (usize, usize),
    goal: (usize, usize),
) -> Option<Vec<(usize, usize)>> {
    if !trav.is_traversable(start.0, start.1) || !trav.is_traversable(goal.0, goal.1) {
        return None;
    }
    // Work on a copy padded by one blocked cell all round: neighbour lookups need no bounds checks.
    let (w, h) = (trav.width + 2, trav.height + 2);
    let mut open_cell = vec![false; w * h];
    for (j, row) in trav.traversable.chunks_exact(trav.width.max(1)).enumerate() {
        open_cell[(j + 1) * w + 1..(j + 1) * w + 1 + trav.width].copy_from_slice(row);
    }
    let index = |(i, j): (usize, usize)| (j + 1) * w + i + 1;
    let (s, g) = (index(start), index(goal));
    let (gi, gj) = (g % w, g / w);
    let heuristic = |k: usize| {
        let (dx, dy) = ((k % w).abs_diff(gi) as f32, (k / w).abs_diff(gj) as f32);
        dx.max(dy) + (SQRT_2 - 1.0) * dx.min(dy)
    };
    // Neighbour offsets: four straight steps, then four diagonals with the two straight
    // neighbours they brush past (no cutting corners).
    let (e, n) = (1isize, w as isize);
    let straight = [e, -e, n, -n];
    let diagonal = [(e + n, e, n), (e - n, e, -n), (-e + n, -e, n), (-e - n, -e, -n)];

    let mut cost = vec![f32::INFINITY; w * h];
    let mut parent = vec![u32::MAX; w * h];
    let mut closed = vec![false; w * h];
    let mut open = BinaryHeap::new();
    cost[s] = 0.0;
    open.push(Open { f: heuristic(s), g: 0.0, k: s as u32 });

    while let Some(Open { g: g_k, k, .. }) = open.pop() {
        let k = k as usize;
        if closed[k] {
            continue;
        }
        if k == g {
            return Some(walk_back(&parent, s, g, w));
        }
        closed[k] = true;
        let at = |d: isize| k.wrapping_add_signed(d);
        let mut relax = |m: usize, step: f32, open: &mut BinaryHeap<Open>| {
            let g_m = g_k + step;
            if !closed[m] && g_m < cost[m] {
                cost[m] = g_m;
                parent[m] = k as u32;
                open.push(Open { f: g_m + heuristic(m), g: g_m, k: m as u32 });
            }
        };
        for d in straight {
            if open_cell[at(d)] {
                relax(at(d), 1.0, &mut open);
            }
        }
        for (d, a, b) in diagonal {
            if open_cell[at(d)] && open_cell[at(a)] && open_cell[at(b)] {
                relax(at(d), SQRT_2, &mut open);
            }
        }
    }
    None
}

/// Follows parents from the goal back to the start (padded indices) and unpads.
fn walk_back(parent: &[u32], start: usize, goal: usize, w: usize) -> Vec<(usize, usize)> {
    let unpad = |k: usize| (k % w - 1, k / w - 1);
    let mut path = vec![unpad(goal)];
    let mut k = goal;
    while k != start {
        k = parent[k] as usize;
        path.push(unpad(k));
    }
    path.reverse();
    path
}

/// Heap entry: lowest `f` first; among equal `f`, the deeper node (larger `g`) first.
#[derive(Clone, Copy, Debug)]
struct Open {
    f: f32,
    g: f32,
    k: u32,
}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> Ordering {
        other.f.total_cmp(&self.f).then(self.g.total_cmp(&other.g)).then(other.k.cmp(&self.k))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Open {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Open {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::map::occupancy::Cell;

    fn all_free(map: &OccupancyMap) -> TraversableMap {
        let traversable: Vec<bool> = map.cells.iter().map(|&c| c == Cell::Free).collect();
        let cells = (0..traversable.len())
            .filter(|&k| traversable[k])
            .map(|k| ((k % map.width) as u32, (k / map.width) as u32))
            .collect();
        TraversableMap { width: map.width, height: map.height, traversable, cells }
    }

    fn length(path: &[(f32, f32)]) -> f32 {
        path.windows(2).map(|s| (s[1].0 - s[0].0).hypot(s[1].1 - s[0].1)).sum()
    }

    #[test]
    fn path_goes_around_a_wall() {
        let map = OccupancyMap::from_ascii(
            1.0,
            "
            .......
            ...#...
            ...#...
            ...#...
            .......
            ",
        );
        let trav = all_free(&map);
        let path = plan_path(&trav, &map, (1.5, 2.5), (5.5, 2.5)).expect("a way round exists");
        assert_eq!(path.first(), Some(&(1.5, 2.5)), "starts at the start cell's centre");
        assert_eq!(path.last(), Some(&(5.5, 2.5)), "ends at the goal cell's centre");
        for &(x, y) in &path {
            let (i, j) = map.cell_at(x, y).expect("on map");
            assert!(trav.is_traversable(i, j), "path crosses ({i}, {j})");
        }
        for s in path.windows(2) {
            let step = (s[1].0 - s[0].0).abs().max((s[1].1 - s[0].1).abs());
            assert_eq!(step, 1.0, "consecutive cells are neighbours: {s:?}");
        }
        let expected = 4.0 + 2.0 * SQRT_2; // up past the wall end, across the top, down again
        assert!((length(&path) - expected).abs() < 1e-4, "optimal length {expected}, got {}", length(&path));
    }

    #[test]
    fn no_corner_cutting_between_diagonal_obstacles() {
        let map = OccupancyMap::from_ascii(
            1.0,
            "
            ...
            .#.
            #..
            ",
        );
        let path = plan_path(&all_free(&map), &map, (0.5, 1.5), (1.5, 0.5)).expect("reachable");
        assert!(path.len() > 2, "the diagonal squeeze between two blocked cells is refused: {path:?}");
        assert!(plan_path(&all_free(&map), &map, (0.5, 1.5), (0.5, 0.5)).is_none(), "(0,0) is blocked");
    }

    #[test]
    fn unreachable_goal_gives_none() {
        let map = OccupancyMap::from_ascii(
            1.0,
            "
            ..#..
            ..#..
            ..#..
            ",
        );
        let trav = all_free(&map);
        assert!(plan_path(&trav, &map, (0.5, 0.5), (4.5, 2.5)).is_none(), "wall splits the map");
        assert!(plan_path(&trav, &map, (0.5, 0.5), (9.5, 0.5)).is_none(), "goal off the map");
    }

    #[test]
    fn open_space_path_is_nearly_straight() {
        let map = OccupancyMap::filled(60, 60, 0.05, Cell::Free);
        let trav = all_free(&map);
        let (start, goal) = ((0.125, 0.125), (2.775, 1.825));
        let path = plan_path(&trav, &map, start, goal).expect("open space");
        let straight = (goal.0 - start.0).hypot(goal.1 - start.1);
        let ratio = length(&path) / straight;
        assert!((1.0 - 1e-4..1.09).contains(&ratio), "octile path / straight line = {ratio}");
    }
}
