//! Where the belief crops are centred: the estimate first (the paper's choice), then the heaviest
//! other modes of the particle set, found as the heaviest square bins of the (x, y) histogram.

use crate::particles::ParticleSet;
use crate::world::Pose2;
use bevy::platform::collections::HashMap;

/// Weighted sums of one bin's particles: enough for its mean pose.
#[derive(Default, Clone, Copy)]
struct BinSums {
    w: f32,
    wx: f32,
    wy: f32,
    wcos: f32,
    wsin: f32,
}

/// `count` crop centres: `estimate`, then the weighted mean poses (circular mean heading) of the
/// `count − 1` heaviest `bin_m` bins other than the estimate's own, by the set's normalised
/// `weights`. With fewer such bins the
/// estimate is repeated, so every robot gets the same number of crops (a fixed batch shape).
pub fn belief_modes(
    set: &ParticleSet,
    weights: &[f32],
    estimate: &Pose2,
    count: usize,
    bin_m: f32,
) -> Vec<Pose2> {
    if count <= 1 {
        return vec![*estimate];
    }
    let bin = |x: f32, y: f32| ((x / bin_m).floor() as i64, (y / bin_m).floor() as i64);
    let mut bins: HashMap<(i64, i64), BinSums> = HashMap::default();
    for (k, &w) in weights.iter().enumerate() {
        let (s, c) = set.yaw[k].sin_cos();
        let sums = bins.entry(bin(set.x[k], set.y[k])).or_default();
        *sums = BinSums {
            w: sums.w + w,
            wx: sums.wx + w * set.x[k],
            wy: sums.wy + w * set.y[k],
            wcos: sums.wcos + w * c,
            wsin: sums.wsin + w * s,
        };
    }
    bins.remove(&bin(estimate.x, estimate.y));
    let mut heaviest: Vec<((i64, i64), BinSums)> = bins.into_iter().collect();
    // Ties broken by the bin's key, so the order never depends on the hash map's.
    heaviest.sort_by(|a, b| b.1.w.total_cmp(&a.1.w).then(a.0.cmp(&b.0)));
    let mut centres = vec![*estimate];
    for (_, sums) in heaviest.into_iter().take(count - 1) {
        let w = sums.w.max(f32::MIN_POSITIVE);
        centres.push(Pose2::new(sums.wx / w, sums.wy / w, sums.wsin.atan2(sums.wcos)));
    }
    centres.resize(count, *estimate);
    centres
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_follow_the_estimate_heaviest_first() {
        let poses = [
            Pose2::new(0.2, 0.2, 0.0),
            Pose2::new(5.2, 0.3, 3.0),
            Pose2::new(5.4, 0.5, -3.0),
            Pose2::new(9.5, 9.5, 1.0),
        ];
        let mut set = ParticleSet::from_poses(&poses);
        set.log_w = [0.4f32, 0.2, 0.2, 0.2].iter().map(|w| w.ln()).collect();
        let estimate = Pose2::new(0.3, 0.3, 0.1);
        let modes = belief_modes(&set, &set.weights(), &estimate, 3, 1.0);
        assert_eq!(modes[0], estimate);
        assert!((modes[1].x - 5.3).abs() < 1e-5 && (modes[1].y - 0.4).abs() < 1e-5, "{modes:?}");
        assert!(
            (modes[1].yaw.abs() - std::f32::consts::PI).abs() < 1e-4,
            "circular mean of ±3 rad: {modes:?}"
        );
        assert!(modes[2].distance(&poses[3]) < 1e-5, "then the lighter bin: {modes:?}");
    }

    #[test]
    fn missing_modes_repeat_the_estimate() {
        let set = ParticleSet::from_poses(&[Pose2::new(0.2, 0.2, 0.0)]);
        let estimate = Pose2::new(0.2, 0.2, 0.0);
        assert_eq!(
            belief_modes(&set, &set.weights(), &estimate, 3, 1.0),
            vec![estimate; 3],
            "the only bin is the estimate's"
        );
    }
}
