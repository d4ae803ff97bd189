//! ⑤ Act: differential drive and one rapier physics world per map.
