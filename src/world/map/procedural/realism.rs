//! The realism layer: roughens a clean apartment so that it looks like a 0.05 m SLAM map of a
//! furnished flat. Walls get runs of uneven thickness, ragged faces and small gaps; furniture is
//! drawn as a scanner sees it (outlines around unknown space, edges, legs, round and slanted
//! tables, chairs); small clutter stands about. Outside the outer walls stays unknown.
//!
//! The robot's free space must survive: restyled furniture stays inside its footprint, gaps and
//! notches only free cells, and nothing is added in front of a door. What can still narrow a
//! passage (thicker walls, bumps, clutter) is checked afterwards: every room the robot reached
//! in the clean map must stay reachable, with most of its traversable area, or the layer is
//! redrawn from the next stream, and in the end drawn without the features that add obstacles.

use super::furniture::{Kind, Piece};
use super::params::{CellParams, RealismParams};
use super::rect::CellRect;
use super::rooms::FloorPlan;
use crate::world::map::{Cell, OccupancyMap, TraversableMap};
use crate::world::rng::stream;
use crate::world::robot::RobotParams;
use rand::Rng;

/// Stream key of the layer, apart from the plan's and the furniture's.
const STAGE_REALISM: u64 = 0x7265_616c;
/// Sub-streams per feature, so switching one feature off leaves the others' draws unchanged.
const STEP_FURNITURE: u64 = 1;
const STEP_WALLS: u64 = 2;
const STEP_GAPS: u64 = 3;
const STEP_CLUTTER: u64 = 4;
/// Draws tried before falling back to the layer without added obstacles (one nearly always does).
const ATTEMPTS: u64 = 4;
/// Share of the clean map's traversable cells that must stay traversable (thicker walls and
/// clutter take a few per cent).
const KEPT_SHARE: f32 = 0.9;

/// The clean map roughened by `r`, from its own stream of `seed`; `clean` itself when the layer
/// is off or changes nothing.
pub(super) fn roughen(
    clean: OccupancyMap,
    plan: &FloorPlan,
    pieces: &[Piece],
    p: &CellParams,
    r: &RealismParams,
    seed: u64,
) -> OccupancyMap {
    if !r.enabled {
        return clean;
    }
    let radius = RobotParams::default().radius_m;
    let Ok(before) = TraversableMap::build(&clean, radius) else { return clean };
    let layer = Layer::new(&clean, plan, pieces, p, r);
    for attempt in 0..ATTEMPTS {
        let map = layer.draw(seed, attempt, true);
        if keeps_robot_space(&before, &map, plan, p, radius) {
            return map;
        }
    }
    layer.draw(seed, ATTEMPTS, false)
}

/// Whether the robot still reaches every room it reached before, keeping most of its space.
fn keeps_robot_space(
    before: &TraversableMap,
    after: &OccupancyMap,
    plan: &FloorPlan,
    p: &CellParams,
    radius_m: f32,
) -> bool {
    let Ok(now) = TraversableMap::build(after, radius_m) else { return false };
    let kept = before.cells.iter().filter(|&&(i, j)| now.is_traversable(i as usize, j as usize)).count();
    if (kept as f32) < KEPT_SHARE * before.cells.len() as f32 {
        return false;
    }
    let reaches = |t: &TraversableMap, r: CellRect| {
        (r.y0..r.y1).any(|j| (r.x0..r.x1).any(|i| t.is_traversable(i as usize, j as usize)))
    };
    plan.rooms
        .iter()
        .map(|room| room.rect.inset(p.wall_hi, p.wall_lo))
        .all(|inner| !reaches(before, inner) || reaches(&now, inner))
}

/// One side of a room's floor along a wall: its cells in order and the direction into the room.
struct Face {
    cells: Vec<(i32, i32)>,
    inward: (i32, i32),
}

/// The four wall faces of a room interior.
fn faces(inner: CellRect) -> [Face; 4] {
    let column = |x: i32, inward| Face { cells: (inner.y0..inner.y1).map(|y| (x, y)).collect(), inward };
    let row = |y: i32, inward| Face { cells: (inner.x0..inner.x1).map(|x| (x, y)).collect(), inward };
    [
        column(inner.x0, (1, 0)),
        column(inner.x1 - 1, (-1, 0)),
        row(inner.y0, (0, 1)),
        row(inner.y1 - 1, (0, -1)),
    ]
}

/// A drawn outline: axis-aligned rectangle, disc, or rectangle turned about its centre.
/// Coordinates are in cells; a cell belongs to the shape when its centre does.
#[derive(Clone, Copy, Debug)]
enum Shape {
    Rect(CellRect),
    Disc { cx: f32, cy: f32, radius: f32 },
    Turned { cx: f32, cy: f32, half_a: f32, half_b: f32, cos: f32, sin: f32 },
}

impl Shape {
    /// The disc inscribed in the square `r` (as the clean generator draws round pieces).
    fn disc_in(r: CellRect) -> Shape {
        let side = r.width().min(r.height()) as f32;
        Shape::Disc { cx: (r.x0 + r.x1) as f32 / 2.0, cy: (r.y0 + r.y1) as f32 / 2.0, radius: side / 2.0 }
    }

    /// The largest copy of `r` turned by `angle` (rad) about its centre that still fits in `r`,
    /// or `None` if it would be too small to read as furniture.
    fn turned_in(r: CellRect, angle: f32) -> Option<Shape> {
        let (w, h) = (r.width() as f32, r.height() as f32);
        let (sin, cos) = angle.sin_cos();
        let (s, c) = (sin.abs(), cos.abs());
        let scale = (w / (w * c + h * s)).min(h / (w * s + h * c));
        let (a, b) = (w * scale, h * scale);
        (a.min(b) >= 4.0).then_some(Shape::Turned {
            cx: (r.x0 + r.x1) as f32 / 2.0,
            cy: (r.y0 + r.y1) as f32 / 2.0,
            half_a: a / 2.0,
            half_b: b / 2.0,
            cos,
            sin,
        })
    }

    fn contains(&self, x: f32, y: f32) -> bool {
        match *self {
            Shape::Rect(r) => x >= r.x0 as f32 && x < r.x1 as f32 && y >= r.y0 as f32 && y < r.y1 as f32,
            Shape::Disc { cx, cy, radius } => (x - cx).hypot(y - cy) <= radius,
            Shape::Turned { cx, cy, half_a, half_b, cos, sin } => {
                let (dx, dy) = (x - cx, y - cy);
                (cos * dx + sin * dy).abs() <= half_a && (-sin * dx + cos * dy).abs() <= half_b
            }
        }
    }

    /// Whether cell (i, j) belongs to the shape.
    fn holds(&self, i: i32, j: i32) -> bool {
        self.contains(i as f32 + 0.5, j as f32 + 0.5)
    }

    /// Leg positions: cells one cell in from each corner, with the direction towards the centre.
    fn leg_cells(&self) -> Vec<((i32, i32), (i32, i32))> {
        match *self {
            Shape::Rect(r) => vec![
                ((r.x0, r.y0), (1, 1)),
                ((r.x1 - 1, r.y0), (-1, 1)),
                ((r.x0, r.y1 - 1), (1, -1)),
                ((r.x1 - 1, r.y1 - 1), (-1, -1)),
            ],
            Shape::Disc { .. } => Vec::new(),
            Shape::Turned { cx, cy, half_a, half_b, cos, sin } => {
                let (a, b) = (half_a - 1.0, half_b - 1.0);
                [(a, b), (-a, b), (a, -b), (-a, -b)]
                    .into_iter()
                    .map(|(u, v)| {
                        let (x, y) = (cx + cos * u - sin * v, cy + sin * u + cos * v);
                        let toward = |d: f32| if d > 0.0 { -1 } else { 1 };
                        ((x.floor() as i32, y.floor() as i32), (toward(x - cx), toward(y - cy)))
                    })
                    .collect()
            }
        }
    }
}

/// What the layer works from: the clean map and where it may and may not draw.
struct Layer<'a> {
    clean: &'a OccupancyMap,
    plan: &'a FloorPlan,
    pieces: &'a [Piece],
    p: &'a CellParams,
    r: RealismParams,
    /// Wall cells of the clean map (occupied and not furniture).
    wall: Vec<bool>,
    /// Cells of a piece's footprint: only its own restyling draws there.
    footprint: Vec<bool>,
    /// Cells in front of a door: never obstructed.
    doorway: Vec<bool>,
}

impl<'a> Layer<'a> {
    fn new(
        clean: &'a OccupancyMap,
        plan: &'a FloorPlan,
        pieces: &'a [Piece],
        p: &'a CellParams,
        r: &RealismParams,
    ) -> Self {
        let mask = |rects: &mut dyn Iterator<Item = CellRect>| {
            let mut m = vec![false; clean.cells.len()];
            for rect in rects {
                for j in rect.y0.max(0)..rect.y1.min(clean.height as i32) {
                    for i in rect.x0.max(0)..rect.x1.min(clean.width as i32) {
                        m[j as usize * clean.width + i as usize] = true;
                    }
                }
            }
            m
        };
        let footprint = mask(&mut pieces.iter().map(|piece| piece.rect));
        let doorway = mask(&mut plan.openings.iter().map(|o| o.keep_clear));
        let wall =
            (0..clean.cells.len()).map(|k| clean.cells[k] == Cell::Occupied && !footprint[k]).collect();
        Self { clean, plan, pieces, p, r: sanitized(r), wall, footprint, doorway }
    }

    /// One draw of the layer; `obstacles` false leaves out whatever could narrow a passage.
    fn draw(&self, seed: u64, attempt: u64, obstacles: bool) -> OccupancyMap {
        let mut map = self.clean.clone();
        let rng = |step| stream(&[seed, STAGE_REALISM, attempt, step]);
        let mut furniture_rng = rng(STEP_FURNITURE);
        for piece in self.pieces {
            self.restyle(&mut map, piece, &mut furniture_rng);
        }
        self.roughen_walls(&mut map, &mut rng(STEP_WALLS), obstacles);
        self.cut_gaps(&mut map, &mut rng(STEP_GAPS));
        if obstacles {
            self.scatter_clutter(&mut map, &mut rng(STEP_CLUTTER));
        }
        map
    }

    fn cells(&self, m: f32) -> i32 {
        self.p.cells(m)
    }

    /// Index of cell (i, j), or `None` off the map.
    fn at(&self, (i, j): (i32, i32)) -> Option<usize> {
        let (w, h) = (self.clean.width as i32, self.clean.height as i32);
        (i >= 0 && j >= 0 && i < w && j < h).then(|| (j * w + i) as usize)
    }

    fn cell(&self, map: &OccupancyMap, c: (i32, i32)) -> Option<Cell> {
        self.at(c).map(|k| map.cells[k])
    }

    // ----- furniture -----

    /// Draws one piece as a scanner sees it, inside its footprint only.
    fn restyle(&self, map: &mut OccupancyMap, piece: &Piece, rng: &mut impl Rng) {
        let r = &self.r;
        let fp = piece.rect;
        match piece.kind {
            Kind::Table => {
                if rng.random_bool(r.slant_probability) {
                    let angle =
                        rng.random_range(0.17f32..=0.79) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    if let Some(shape) = Shape::turned_in(fp, angle) {
                        self.clear(map, fp);
                        if rng.random_bool(r.legs_probability) {
                            self.legs(map, &shape, fp, rng);
                        } else {
                            self.outline(map, &shape, fp);
                        }
                        return;
                    }
                }
                if rng.random_bool(r.round_table_probability) {
                    self.clear(map, fp);
                    self.outline(map, &Shape::disc_in(fp), fp);
                } else if rng.random_bool(r.legs_probability) {
                    self.clear(map, fp);
                    self.table_with_chairs(map, fp, rng);
                } else {
                    self.solid_or_outline(map, piece, rng);
                }
            }
            Kind::Desk if rng.random_bool(r.legs_probability) => {
                self.clear(map, fp);
                self.legs(map, &Shape::Rect(fp), fp, rng);
            }
            Kind::Bed | Kind::Sofa if rng.random_bool(r.partial_outline_probability) => {
                if !self.edges(map, fp, rng) {
                    self.solid_or_outline(map, piece, rng);
                }
            }
            _ => self.solid_or_outline(map, piece, rng),
        }
    }

    /// The clean black block, or a one-cell outline around unknown space.
    fn solid_or_outline(&self, map: &mut OccupancyMap, piece: &Piece, rng: &mut impl Rng) {
        if rng.random_bool(self.r.outline_probability) {
            let shape = if piece.round { Shape::disc_in(piece.rect) } else { Shape::Rect(piece.rect) };
            self.clear(map, piece.rect);
            self.outline(map, &shape, piece.rect);
        }
    }

    fn clear(&self, map: &mut OccupancyMap, fp: CellRect) {
        self.paint(map, fp, |_, _| Some(Cell::Free));
    }

    /// Sets the cells of `fp` that `cell_at` names.
    fn paint(&self, map: &mut OccupancyMap, fp: CellRect, cell_at: impl Fn(i32, i32) -> Option<Cell>) {
        for j in fp.y0..fp.y1 {
            for i in fp.x0..fp.x1 {
                if let (Some(k), Some(cell)) = (self.at((i, j)), cell_at(i, j)) {
                    map.cells[k] = cell;
                }
            }
        }
    }

    /// The shape's rim occupied, its inside unknown (never seen by the scanner).
    fn outline(&self, map: &mut OccupancyMap, shape: &Shape, fp: CellRect) {
        self.paint(map, fp, |i, j| {
            if !shape.holds(i, j) {
                return None;
            }
            let rim = [(1, 0), (-1, 0), (0, 1), (0, -1)].iter().any(|&(di, dj)| !shape.holds(i + di, j + dj));
            Some(if rim { Cell::Occupied } else { Cell::Unknown })
        });
    }

    /// A leg dot of 2–4 cells at each corner of `shape`, kept inside `fp`.
    fn legs(&self, map: &mut OccupancyMap, shape: &Shape, fp: CellRect, rng: &mut impl Rng) {
        for ((i, j), (di, dj)) in shape.leg_cells() {
            let (w, h) = [(1, 2), (2, 1), (2, 2)][rng.random_range(0..3)];
            for b in 0..h {
                for a in 0..w {
                    let c = (i + a * di, j + b * dj);
                    if fp.x0 <= c.0 && c.0 < fp.x1 && fp.y0 <= c.1 && c.1 < fp.y1 {
                        self.paint(map, CellRect::new(c.0, c.1, c.0 + 1, c.1 + 1), |_, _| {
                            Some(Cell::Occupied)
                        });
                    }
                }
            }
        }
    }

    /// A table on legs within the footprint, chairs (four leg dots each) along some sides where
    /// the footprint leaves room for them beside a table of at least 0.6 m.
    fn table_with_chairs(&self, map: &mut OccupancyMap, fp: CellRect, rng: &mut impl Rng) {
        let (seat, stand_out, least) = (self.cells(0.4).max(2), self.cells(0.25).max(1), self.cells(0.6));
        let mut table = fp;
        let mut with_chairs = [false; 4];
        for (side, chairs) in with_chairs.iter_mut().enumerate() {
            let across = if side < 2 { table.width() } else { table.height() };
            if rng.random_bool(self.r.chair_probability) && across - stand_out >= least.max(seat) {
                match side {
                    0 => table.x0 += stand_out,
                    1 => table.x1 -= stand_out,
                    2 => table.y0 += stand_out,
                    _ => table.y1 -= stand_out,
                }
                *chairs = true;
            }
        }
        self.legs(map, &Shape::Rect(table), fp, rng);
        let spacing = seat + self.cells(0.2);
        for side in (0..4).filter(|&s| with_chairs[s]) {
            let (lo, hi) = if side < 2 { (table.y0, table.y1) } else { (table.x0, table.x1) };
            let n = ((hi - lo) / spacing).clamp(1, 3);
            if hi - lo < seat {
                continue;
            }
            for k in 0..n {
                let start = lo + (hi - lo) * (2 * k + 1) / (2 * n) - seat / 2;
                let chair = match side {
                    0 => CellRect::new(fp.x0, start, fp.x0 + seat, start + seat),
                    1 => CellRect::new(fp.x1 - seat, start, fp.x1, start + seat),
                    2 => CellRect::new(start, fp.y0, start + seat, fp.y0 + seat),
                    _ => CellRect::new(start, fp.y1 - seat, start + seat, fp.y1),
                };
                self.legs(map, &Shape::Rect(chair), fp, rng);
            }
        }
    }

    /// One-cell lines on 1–3 of the room-facing sides of `fp`, the floor beneath free; at least
    /// one room-facing side stays open so the floor beneath never becomes a closed pocket.
    /// False if the piece faces the room on fewer than two sides.
    fn edges(&self, map: &mut OccupancyMap, fp: CellRect, rng: &mut impl Rng) -> bool {
        let (mid_x, mid_y) = ((fp.x0 + fp.x1) / 2, (fp.y0 + fp.y1) / 2);
        let beyond = [(fp.x0 - 1, mid_y), (fp.x1, mid_y), (mid_x, fp.y0 - 1), (mid_x, fp.y1)];
        let mut facing: Vec<usize> =
            (0..4).filter(|&s| !self.at(beyond[s]).is_some_and(|k| self.wall[k])).collect();
        if facing.len() < 2 {
            return false;
        }
        let drawn = rng.random_range(1..=(facing.len() - 1).min(3));
        for k in 0..drawn {
            let pick = rng.random_range(k..facing.len());
            facing.swap(k, pick);
        }
        self.clear(map, fp);
        for &side in &facing[..drawn] {
            let line = match side {
                0 => CellRect::new(fp.x0, fp.y0, fp.x0 + 1, fp.y1),
                1 => CellRect::new(fp.x1 - 1, fp.y0, fp.x1, fp.y1),
                2 => CellRect::new(fp.x0, fp.y0, fp.x1, fp.y0 + 1),
                _ => CellRect::new(fp.x0, fp.y1 - 1, fp.x1, fp.y1),
            };
            self.paint(map, line, |_, _| Some(Cell::Occupied));
        }
        true
    }

    // ----- walls -----

    /// Runs of thicker or thinner wall along every face, and one-cell bumps and notches.
    /// Thickening and bumps (added obstacles) only when `obstacles`.
    fn roughen_walls(&self, map: &mut OccupancyMap, rng: &mut impl Rng, obstacles: bool) {
        let r = &self.r;
        let thicken_max = self.cells(r.wall_thicken_max_m);
        let (run_min, run_max) = (self.cells(0.3).max(1), self.cells(1.5).max(1));
        for room in &self.plan.rooms {
            for face in faces(room.rect.inset(self.p.wall_hi, self.p.wall_lo)) {
                let mut start = 0;
                while start < face.cells.len() {
                    let run = rng.random_range(run_min..=run_max) as usize;
                    let change = if rng.random_bool(r.wall_jitter_probability) {
                        if rng.random_bool(0.4) { rng.random_range(1..=thicken_max.max(1)) } else { -1 }
                    } else {
                        0
                    };
                    for &c in &face.cells[start..(start + run).min(face.cells.len())] {
                        if change < 0 {
                            self.notch(map, c, face.inward);
                        } else if change > 0 && obstacles && thicken_max > 0 {
                            self.thicken(map, c, face.inward, change);
                        }
                        if rng.random_bool(r.wall_noise_probability) {
                            if rng.random_bool(0.5) {
                                self.notch(map, c, face.inward);
                            } else if obstacles {
                                self.thicken(map, c, face.inward, 1);
                            }
                        }
                    }
                    start += run;
                }
            }
        }
    }

    /// Grows the wall behind face cell `c` up to `depth` cells into the room, never onto
    /// furniture or in front of a door.
    fn thicken(&self, map: &mut OccupancyMap, c: (i32, i32), inward: (i32, i32), depth: i32) {
        let behind = (c.0 - inward.0, c.1 - inward.1);
        if self.cell(map, behind) != Some(Cell::Occupied) {
            return;
        }
        for d in 0..depth {
            let Some(k) = self.at((c.0 + d * inward.0, c.1 + d * inward.1)) else { return };
            if map.cells[k] != Cell::Free || self.footprint[k] || self.doorway[k] {
                return;
            }
            map.cells[k] = Cell::Occupied;
        }
    }

    /// Frees the wall cell behind face cell `c` when the wall stays at least one cell thick.
    fn notch(&self, map: &mut OccupancyMap, c: (i32, i32), inward: (i32, i32)) {
        let wall_cell = (c.0 - inward.0, c.1 - inward.1);
        let next = (c.0 - 2 * inward.0, c.1 - 2 * inward.1);
        if let Some(k) = self.at(wall_cell)
            && self.wall[k]
            && map.cells[k] == Cell::Occupied
            && self.cell(map, c) == Some(Cell::Free)
            && self.cell(map, next) == Some(Cell::Occupied)
        {
            map.cells[k] = Cell::Free;
        }
    }

    /// Small gaps (one to a few cells, narrower than the robot) cut right through walls, away
    /// from doors and from each other so that no two of them add up to a passage.
    fn cut_gaps(&self, map: &mut OccupancyMap, rng: &mut impl Rng) {
        let r = &self.r;
        if r.wall_gaps_per_m <= 0.0 {
            return;
        }
        let narrowest = self.cells(r.wall_gap_min_m).max(1);
        let widest = self.cells(r.wall_gap_max_m).max(narrowest);
        let corner = self.cells(0.15).max(1);
        let mut cut = vec![false; map.cells.len()];
        for room in &self.plan.rooms {
            for face in faces(room.rect.inset(self.p.wall_hi, self.p.wall_lo)) {
                let len = face.cells.len() as i32;
                let len_m = len as f32 * self.p.resolution_m;
                let count = (len_m * r.wall_gaps_per_m + rng.random::<f32>()).floor() as usize;
                for _ in 0..count {
                    let width = rng.random_range(narrowest..=widest);
                    if len < 2 * corner + width {
                        continue;
                    }
                    let at = rng.random_range(corner..=len - corner - width);
                    let near_door = (at - 1..at + width + 1)
                        .any(|t| self.at(face.cells[t as usize]).is_some_and(|k| self.doorway[k]));
                    if near_door {
                        continue;
                    }
                    let cells: Vec<usize> = (at..at + width)
                        .filter_map(|t| self.cells_across(map, face.cells[t as usize], face.inward))
                        .flatten()
                        .collect();
                    if cells.iter().any(|&k| self.near(&cut, k, 2)) {
                        continue;
                    }
                    for k in cells {
                        map.cells[k] = Cell::Free;
                        cut[k] = true;
                    }
                }
            }
        }
    }

    /// The wall cells on the line through face cell `c` across the wall, from the room's first
    /// free cell to the free or unknown space beyond; `None` if the line meets furniture or
    /// crosses more than one wall's thickness (it would run along a wall or a door's jamb).
    fn cells_across(&self, map: &OccupancyMap, c: (i32, i32), inward: (i32, i32)) -> Option<Vec<usize>> {
        let step = |c: (i32, i32), n: i32| (c.0 + n * inward.0, c.1 + n * inward.1);
        let thicken_max = self.cells(self.r.wall_thicken_max_m);
        let first_free = (0..=thicken_max + 1).find(|&n| self.cell(map, step(c, n)) == Some(Cell::Free))?;
        let wall_thickness = (self.p.wall_lo + self.p.wall_hi) as usize;
        let mut cells = Vec::new();
        for n in 1.. {
            let k = self.at(step(c, first_free - n))?;
            if self.footprint[k] || cells.iter().filter(|&&k| self.wall[k]).count() > wall_thickness {
                return None;
            }
            if map.cells[k] != Cell::Occupied {
                return Some(cells);
            }
            cells.push(k);
        }
        None
    }

    /// Whether `mask` is set within `reach` cells (Chebyshev) of cell `k`.
    fn near(&self, mask: &[bool], k: usize, reach: i32) -> bool {
        let w = self.clean.width;
        let (i, j) = ((k % w) as i32, (k / w) as i32);
        (-reach..=reach)
            .any(|dj| (-reach..=reach).any(|di| self.at((i + di, j + dj)).is_some_and(|n| mask[n])))
    }

    // ----- clutter -----

    /// Small blobs (bins, pots, bags) on the floor: half against a wall, half free-standing at
    /// least the furniture clearance from anything else; never in front of a door or on furniture.
    fn scatter_clutter(&self, map: &mut OccupancyMap, rng: &mut impl Rng) {
        let r = &self.r;
        let inners: Vec<CellRect> =
            self.plan.rooms.iter().map(|room| room.rect.inset(self.p.wall_hi, self.p.wall_lo)).collect();
        let total: i64 = inners.iter().map(CellRect::area).sum();
        if total <= 0 || r.clutter_per_m2 <= 0.0 {
            return;
        }
        let count = (self.p.area_m2(total) * r.clutter_per_m2 + rng.random::<f32>()).floor() as usize;
        let largest = self.cells(r.clutter_max_m).max(1);
        for _ in 0..count {
            for _try in 0..20 {
                let mut pick = rng.random_range(0..total);
                let inner = *inners
                    .iter()
                    .find(|rect| {
                        let hit = pick < rect.area();
                        pick -= rect.area();
                        hit
                    })
                    .unwrap_or(&inners[0]);
                let (w, h) = (rng.random_range(1..=largest), rng.random_range(1..=largest));
                let blob = if rng.random_bool(0.5) {
                    let face = &faces(inner)[rng.random_range(0..4)];
                    let (x, y) = face.cells[rng.random_range(0..face.cells.len())];
                    let behind = (x - face.inward.0, y - face.inward.1);
                    if self.cell(map, behind) != Some(Cell::Occupied) {
                        continue;
                    }
                    let (x0, y0) = (
                        if face.inward.0 < 0 { x - w + 1 } else { x },
                        if face.inward.1 < 0 { y - h + 1 } else { y },
                    );
                    CellRect::new(x0, y0, x0 + w, y0 + h)
                } else {
                    if inner.width() <= w || inner.height() <= h {
                        continue;
                    }
                    let x0 = rng.random_range(inner.x0..inner.x1 - w);
                    let y0 = rng.random_range(inner.y0..inner.y1 - h);
                    let blob = CellRect::new(x0, y0, x0 + w, y0 + h);
                    let c = self.p.clearance;
                    let around = CellRect::new(x0 - c, y0 - c, x0 + w + c, y0 + h + c);
                    if !self.all(map, around, |cell, _| cell == Cell::Free) {
                        continue;
                    }
                    blob
                };
                if !self
                    .all(map, blob, |cell, k| cell == Cell::Free && !self.footprint[k] && !self.doorway[k])
                {
                    continue;
                }
                let round_off = w >= 3 && h >= 3;
                self.paint(map, blob, |i, j| {
                    let corner = (i == blob.x0 || i == blob.x1 - 1) && (j == blob.y0 || j == blob.y1 - 1);
                    (!(round_off && corner)).then_some(Cell::Occupied)
                });
                break;
            }
        }
    }

    /// Whether every cell of `rect` is on the map and passes `ok(cell, index)`.
    fn all(&self, map: &OccupancyMap, rect: CellRect, ok: impl Fn(Cell, usize) -> bool) -> bool {
        (rect.y0..rect.y1)
            .all(|j| (rect.x0..rect.x1).all(|i| self.at((i, j)).is_some_and(|k| ok(map.cells[k], k))))
    }
}

/// The parameters forced into range, so that nonsense values cannot panic the generator.
fn sanitized(r: &RealismParams) -> RealismParams {
    let probability = |p: f64| if p.is_finite() { p.clamp(0.0, 1.0) } else { 0.0 };
    let length = |m: f32, hi: f32| if m.is_finite() { m.clamp(0.0, hi) } else { 0.0 };
    let gap_max = length(r.wall_gap_max_m, 0.3);
    RealismParams {
        enabled: r.enabled,
        wall_jitter_probability: probability(r.wall_jitter_probability),
        wall_thicken_max_m: length(r.wall_thicken_max_m, 0.3),
        wall_noise_probability: probability(r.wall_noise_probability),
        wall_gaps_per_m: length(r.wall_gaps_per_m, 10.0),
        wall_gap_min_m: length(r.wall_gap_min_m, gap_max),
        wall_gap_max_m: gap_max,
        outline_probability: probability(r.outline_probability),
        partial_outline_probability: probability(r.partial_outline_probability),
        legs_probability: probability(r.legs_probability),
        chair_probability: probability(r.chair_probability),
        round_table_probability: probability(r.round_table_probability),
        slant_probability: probability(r.slant_probability),
        clutter_per_m2: length(r.clutter_per_m2, 10.0),
        clutter_max_m: length(r.clutter_max_m, 0.5),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::map::procedural::{ApartmentParams, generate_apartment};

    fn with(realism: RealismParams) -> ApartmentParams {
        ApartmentParams { realism, ..ApartmentParams::default() }
    }

    #[test]
    fn turned_shapes_stay_inside_their_footprint() {
        let fp = CellRect::new(10, 20, 46, 44);
        for angle in [0.17f32, 0.5, -0.79] {
            let shape = Shape::turned_in(fp, angle).expect("a 1.8 × 1.2 m table turns");
            let cells: Vec<(i32, i32)> = (0..80)
                .flat_map(|j| (0..80).map(move |i| (i, j)))
                .filter(|&(i, j)| shape.holds(i, j))
                .collect();
            assert!(cells.len() > 200, "angle {angle}: only {} cells", cells.len());
            assert!(
                cells.iter().all(|&(i, j)| fp.contains(&CellRect::new(i, j, i + 1, j + 1))),
                "angle {angle}: a cell outside the footprint"
            );
            for ((i, j), _) in shape.leg_cells() {
                assert!(shape.holds(i, j), "angle {angle}: leg ({i}, {j}) off the table");
            }
        }
        assert!(Shape::turned_in(CellRect::new(0, 0, 4, 4), 0.5).is_none(), "too small to turn");
    }

    #[test]
    fn default_realism_shows_unknown_furniture_interiors_and_gaps() {
        let clean = with(RealismParams { enabled: false, ..Default::default() });
        let (mut unknown_gained, mut occupied_lost) = (0, 0);
        for seed in 0..5 {
            let (f0, o0, u0) = generate_apartment(seed, &clean).counts();
            let (f1, o1, u1) = generate_apartment(seed, &with(RealismParams::default())).counts();
            assert_eq!(f0 + o0 + u0, f1 + o1 + u1, "same grid");
            unknown_gained += u1.saturating_sub(u0);
            occupied_lost += o0.saturating_sub(o1);
        }
        assert!(unknown_gained > 1000, "outlines should leave unseen interiors, got {unknown_gained} cells");
        assert!(occupied_lost > 1000, "solid blocks should become outlines and legs, lost {occupied_lost}");
    }

    #[test]
    fn wall_gaps_never_open_a_passage_for_the_robot() {
        let only_gaps = RealismParams { wall_gaps_per_m: 3.0, wall_gap_max_m: 0.3, ..RealismParams::none() };
        let radius = RobotParams::default().radius_m;
        for seed in [0, 5, 1_000_001] {
            let clean =
                generate_apartment(seed, &with(RealismParams { enabled: false, ..Default::default() }));
            let gapped = generate_apartment(seed, &with(only_gaps.clone()));
            let opened = gapped.counts().0 - clean.counts().0;
            assert!(opened > 200, "seed {seed}: only {opened} wall cells cut");
            let (before, after) = (
                TraversableMap::build(&clean, radius).expect("space"),
                TraversableMap::build(&gapped, radius).expect("space"),
            );
            // The robot's centre never stands in a cut (which a passage through a wall needs),
            // and it keeps all it had: a gap only widens the room's mouth a little.
            for &(i, j) in &after.cells {
                assert_eq!(
                    clean.get(i as usize, j as usize),
                    Cell::Free,
                    "seed {seed}: robot fits in a gap at ({i}, {j})"
                );
            }
            assert!(
                before.cells.iter().all(|&(i, j)| after.is_traversable(i as usize, j as usize)),
                "seed {seed}"
            );
        }
    }

    #[test]
    fn gaps_are_cut_only_through_walls_never_through_furniture() {
        let only_gaps = RealismParams { wall_gaps_per_m: 3.0, ..RealismParams::none() };
        for seed in [2, 1_000_002] {
            let clean =
                generate_apartment(seed, &with(RealismParams { enabled: false, ..Default::default() }));
            let gapped = generate_apartment(seed, &with(only_gaps.clone()));
            for k in 0..clean.cells.len() {
                let (before, after) = (clean.cells[k], gapped.cells[k]);
                assert!(before == after || (before == Cell::Occupied && after == Cell::Free), "cell {k}");
            }
        }
    }

    #[test]
    fn nonsense_parameters_are_clamped_instead_of_panicking() {
        let nonsense = RealismParams {
            wall_jitter_probability: f64::NAN,
            wall_thicken_max_m: 7.0,
            wall_noise_probability: -1.0,
            wall_gaps_per_m: f32::INFINITY,
            wall_gap_min_m: 0.5,
            wall_gap_max_m: -0.2,
            legs_probability: 3.0,
            clutter_per_m2: 1e9,
            clutter_max_m: f32::NAN,
            ..Default::default()
        };
        assert!(nonsense.validate().is_err(), "validate names the first bad field");
        let map = generate_apartment(4, &with(nonsense));
        assert!(map.counts().0 > 0, "still an apartment with floor");
    }

    #[test]
    fn realism_params_parse_from_ron_under_the_apartment_params() {
        let p: ApartmentParams =
            ron::from_str("(max_side_m: 12.0, realism: (enabled: false))").expect("nested partial RON");
        assert!(!p.realism.enabled);
        assert_eq!(p.realism.clutter_per_m2, RealismParams::default().clutter_per_m2, "others default");
        assert!(
            ron::from_str::<ApartmentParams>("(realism: (gaps: 1.0))").is_err(),
            "unknown fields rejected"
        );
        let wide = ApartmentParams {
            realism: RealismParams { wall_gap_max_m: 0.4, ..Default::default() },
            ..Default::default()
        };
        assert_eq!(
            wide.validate().map_err(|e| e.field),
            Err("realism.wall_gap_max_m"),
            "gap wider than 0.3 m"
        );
        assert_eq!(ApartmentParams::default().validate(), Ok(()));
    }
}
