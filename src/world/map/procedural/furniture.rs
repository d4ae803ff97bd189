//! Furniture: beds, sofas, shelves, counters and desks against walls; tables and pillars standing
//! free. Placed by rejection so that every gap is either closed (touching) or at least the
//! clearance wide, and nothing stands in front of a door: the robot reaches every room and
//! furniture never cuts one in two.

use super::params::CellParams;
use super::rect::CellRect;
use super::rooms::{FloorPlan, RoomRole};
use rand::Rng;

/// One obstacle; a round one is the disc inscribed in its square `rect`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Piece {
    pub rect: CellRect,
    pub round: bool,
    /// What it is, so the realism layer can draw it as a scanner sees it.
    pub kind: Kind,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Bed,
    Sofa,
    Shelf,
    Counter,
    Desk,
    Table,
    Pillar,
}

/// How a kind of furniture stands. Sizes in metres: (least, most).
enum Footing {
    /// Back against a wall: extent along the wall, depth into the room, chance of a corner spot.
    Wall { along: (f32, f32), depth: (f32, f32), corner: f64 },
    /// Clear of every wall by the clearance.
    Free { sides: (f32, f32), square: bool },
}

impl Kind {
    /// Typical European furniture sizes (our choice).
    fn footing(self) -> Footing {
        use Footing::*;
        match self {
            Kind::Bed => Wall { along: (0.9, 1.8), depth: (1.9, 2.1), corner: 0.3 },
            Kind::Sofa => Wall { along: (1.6, 2.4), depth: (0.8, 0.95), corner: 0.2 },
            Kind::Shelf => Wall { along: (0.6, 2.0), depth: (0.3, 0.45), corner: 0.3 },
            Kind::Counter => Wall { along: (1.2, 3.0), depth: (0.6, 0.65), corner: 0.7 },
            Kind::Desk => Wall { along: (1.0, 1.6), depth: (0.6, 0.8), corner: 0.3 },
            Kind::Table => Free { sides: (0.8, 1.8), square: false },
            Kind::Pillar => Free { sides: (0.25, 0.4), square: true },
        }
    }
}

/// What a room may hold, most important first.
fn catalogue(role: RoomRole, area_m2: f32) -> &'static [Kind] {
    use Kind::*;
    match role {
        RoomRole::Corridor => &[],
        RoomRole::Living => &[Sofa, Table, Shelf, Desk, Shelf, Shelf],
        RoomRole::Kitchen => &[Counter, Table, Counter, Shelf],
        RoomRole::Other if area_m2 < 7.0 => &[Shelf, Counter],
        RoomRole::Other => &[Bed, Shelf, Desk, Shelf],
    }
}

/// Furnishes every room but the corridor: about `furniture_per_m2` pieces per m² from the room's
/// catalogue, and sometimes pillars in large rooms.
pub(super) fn furnish(plan: &FloorPlan, p: &CellParams, rng: &mut impl Rng) -> Vec<Piece> {
    let mut pieces = Vec::new();
    for (k, room) in plan.rooms.iter().enumerate().filter(|(_, r)| r.role != RoomRole::Corridor) {
        let inner = room.rect.inset(p.wall_hi, p.wall_lo);
        let keep: Vec<CellRect> =
            plan.openings.iter().filter(|o| o.rooms.0 == k || o.rooms.1 == k).map(|o| o.keep_clear).collect();
        let area_m2 = p.area_m2(inner.area());
        let wanted = (area_m2 * p.furniture_per_m2 + rng.random::<f32>()).floor() as usize;
        let mut here: Vec<Piece> = Vec::new();
        for &kind in catalogue(room.role, area_m2).iter().take(wanted) {
            if let Some(piece) = place(kind, inner, &here, &keep, p, rng) {
                here.push(piece);
            }
        }
        if area_m2 > 20.0 && rng.random_bool(p.pillar_probability) {
            for _ in 0..rng.random_range(1..=2) {
                if let Some(piece) = place(Kind::Pillar, inner, &here, &keep, p, rng) {
                    here.push(piece);
                }
            }
        }
        pieces.extend(here);
    }
    pieces
}

/// Up to 40 random tries to fit one piece of `kind` in the room interior `inner`.
fn place(
    kind: Kind,
    inner: CellRect,
    placed: &[Piece],
    keep: &[CellRect],
    p: &CellParams,
    rng: &mut impl Rng,
) -> Option<Piece> {
    let c = p.clearance;
    for _ in 0..40 {
        let candidate = match kind.footing() {
            Footing::Wall { along, depth, corner } => {
                let side = rng.random_range(0..4);
                let (len, cross) =
                    if side < 2 { (inner.height(), inner.width()) } else { (inner.width(), inner.height()) };
                let a = p.cells(rng.random_range(along.0..=along.1)).max(1);
                let d = p.cells(rng.random_range(depth.0..=depth.1)).max(1);
                if a > len || d + c > cross {
                    continue;
                }
                let pos = if rng.random_bool(corner) {
                    if rng.random_bool(0.5) { 0 } else { len - a }
                } else if len - a >= 2 * c {
                    rng.random_range(c..=len - a - c)
                } else {
                    continue;
                };
                let rect = match side {
                    0 => CellRect::new(inner.x0, inner.y0 + pos, inner.x0 + d, inner.y0 + pos + a),
                    1 => CellRect::new(inner.x1 - d, inner.y0 + pos, inner.x1, inner.y0 + pos + a),
                    2 => CellRect::new(inner.x0 + pos, inner.y0, inner.x0 + pos + a, inner.y0 + d),
                    _ => CellRect::new(inner.x0 + pos, inner.y1 - d, inner.x0 + pos + a, inner.y1),
                };
                Piece { rect, round: false, kind }
            }
            Footing::Free { sides, square } => {
                let w = p.cells(rng.random_range(sides.0..=sides.1)).max(1);
                let h = if square { w } else { p.cells(rng.random_range(sides.0..=sides.1)).max(1) };
                if inner.width() < w + 2 * c || inner.height() < h + 2 * c {
                    continue;
                }
                let x0 = rng.random_range(inner.x0 + c..=inner.x1 - c - w);
                let y0 = rng.random_range(inner.y0 + c..=inner.y1 - c - h);
                Piece {
                    rect: CellRect::new(x0, y0, x0 + w, y0 + h),
                    round: square && rng.random_bool(0.5),
                    kind,
                }
            }
        };
        if fits(&candidate.rect, inner, placed, keep, c) {
            return Some(candidate);
        }
    }
    None
}

/// The placement rules: inside the room; each side either touching a wall or at least `c` from
/// it, never touching two opposite walls; at least `c` from every other piece; off every door's
/// clear zone.
fn fits(rect: &CellRect, inner: CellRect, placed: &[Piece], keep: &[CellRect], c: i32) -> bool {
    let gaps = [rect.x0 - inner.x0, inner.x1 - rect.x1, rect.y0 - inner.y0, inner.y1 - rect.y1];
    inner.contains(rect)
        && gaps.iter().all(|&g| g == 0 || g >= c)
        && !(gaps[0] == 0 && gaps[1] == 0)
        && !(gaps[2] == 0 && gaps[3] == 0)
        && placed.iter().all(|q| rect.gap(&q.rect) >= c as f32)
        && keep.iter().all(|z| !z.intersects(rect))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_rejects_narrow_gaps_doors_and_wall_to_wall_pieces() {
        let inner = CellRect::new(0, 0, 60, 60);
        let c = 12;
        assert!(fits(&CellRect::new(0, 0, 20, 10), inner, &[], &[], c), "corner piece is fine");
        assert!(!fits(&CellRect::new(5, 0, 25, 10), inner, &[], &[], c), "5-cell gap to a wall traps space");
        assert!(
            !fits(&CellRect::new(0, 20, 60, 30), inner, &[], &[], c),
            "touching opposite walls cuts the room"
        );
        let sofa = Piece { rect: CellRect::new(30, 0, 50, 10), round: false, kind: Kind::Sofa };
        assert!(!fits(&CellRect::new(20, 20, 30, 30), inner, &[sofa], &[], c), "gap 10 < 12 to the sofa");
        assert!(fits(&CellRect::new(15, 22, 25, 32), inner, &[sofa], &[], c), "gap ≥ 12 to the sofa");
        let door_zone = CellRect::new(-2, 40, 20, 60);
        assert!(!fits(&CellRect::new(0, 45, 8, 60), inner, &[], &[door_zone], c), "blocks the door");
    }

    #[test]
    fn free_standing_pieces_keep_clear_of_every_wall() {
        let p = CellParams::new(&super::super::ApartmentParams::default());
        let inner = CellRect::new(100, 100, 200, 180);
        let mut rng = crate::world::rng::stream(&[9]);
        for _ in 0..50 {
            let Some(t) = place(Kind::Table, inner, &[], &[], &p, &mut rng) else { continue };
            let gaps =
                [t.rect.x0 - inner.x0, inner.x1 - t.rect.x1, t.rect.y0 - inner.y0, inner.y1 - t.rect.y1];
            assert!(gaps.iter().all(|&g| g >= p.clearance), "table {t:?} too close to a wall");
        }
    }
}
