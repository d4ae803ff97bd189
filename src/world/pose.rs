//! Planar poses in the world frame: metres, x right, y up, yaw counter-clockwise from +x.

use serde::{Deserialize, Serialize};
use std::f32::consts::{PI, TAU};

/// A 2D pose: position in metres, heading in radians wrapped to (−π, π].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose2 {
    pub x: f32,
    pub y: f32,
    pub yaw: f32,
}

impl Pose2 {
    pub const fn new(x: f32, y: f32, yaw: f32) -> Self {
        Self { x, y, yaw }
    }

    /// `self ⊕ delta`: applies a motion expressed in this pose's own frame.
    pub fn compose(&self, delta: &Pose2) -> Pose2 {
        let (s, c) = self.yaw.sin_cos();
        Pose2::new(
            self.x + c * delta.x - s * delta.y,
            self.y + s * delta.x + c * delta.y,
            wrap_angle(self.yaw + delta.yaw),
        )
    }

    /// `self⁻¹ ⊕ other`: the motion from `self` to `other`, in `self`'s frame (what odometry reports).
    pub fn between(&self, other: &Pose2) -> Pose2 {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (other.x - self.x, other.y - self.y);
        Pose2::new(c * dx + s * dy, -s * dx + c * dy, wrap_angle(other.yaw - self.yaw))
    }

    /// Maps a point from this pose's frame into the world frame.
    pub fn transform_point(&self, local_x: f32, local_y: f32) -> (f32, f32) {
        let (s, c) = self.yaw.sin_cos();
        (self.x + c * local_x - s * local_y, self.y + s * local_x + c * local_y)
    }

    pub fn distance(&self, other: &Pose2) -> f32 {
        (self.x - other.x).hypot(self.y - other.y)
    }

    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.yaw.is_finite()
    }
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(angle: f32) -> f32 {
    let wrapped = angle - TAU * ((angle + PI) / TAU).floor();
    // floor maps +π to −π; the convention keeps +π.
    if wrapped <= -PI { wrapped + TAU } else { wrapped }
}

/// Absolute angular difference, in [0, π].
pub fn angle_error(a: f32, b: f32) -> f32 {
    wrap_angle(a - b).abs()
}

/// Weighted circular mean of angles: the heading of Σ w·(cos θ, sin θ).
/// A linear mean breaks near ±π (the reference implementation's bug); this does not.
pub fn circular_mean(angles: &[f32], weights: &[f32]) -> f32 {
    let (mut s, mut c) = (0.0f64, 0.0f64);
    for (&a, &w) in angles.iter().zip(weights) {
        s += w as f64 * (a as f64).sin();
        c += w as f64 * (a as f64).cos();
    }
    s.atan2(c) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_keeps_range_and_plus_pi() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-5);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-5, "−π maps to +π");
        assert!((wrap_angle(0.5 - 4.0 * TAU) - 0.5).abs() < 1e-4);
    }

    #[test]
    fn between_inverts_compose() {
        let a = Pose2::new(1.0, -2.0, 2.9);
        let d = Pose2::new(0.3, 0.1, 0.7);
        let b = a.compose(&d);
        let back = a.between(&b);
        assert!((back.x - d.x).abs() < 1e-5 && (back.y - d.y).abs() < 1e-5);
        assert!(angle_error(back.yaw, d.yaw) < 1e-5);
    }

    #[test]
    fn circular_mean_handles_wraparound() {
        let m = circular_mean(&[PI - 0.1, -PI + 0.1], &[0.5, 0.5]);
        assert!(angle_error(m, PI) < 1e-4, "mean of ±(π−0.1) is π, got {m}");
    }
}
