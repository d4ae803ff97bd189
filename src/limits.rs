//! Sane ranges for every count and size a user's file or flag can set. Loaders check them before
//! allocating anything, so a typo such as `robots_per_map: 100000000` fails in milliseconds with
//! the file and field named instead of aborting on a multi-gigabyte allocation. README "Limits"
//! lists them with the reason for each bound.

/// An inclusive range of counts, with the words errors use for it ("1 to 1,000 robots per map";
/// a test checks that they state `min` and `max`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limit {
    pub min: u64,
    pub max: u64,
    pub expected: &'static str,
}

/// Robots on one map (the repo's scenes use 1–10).
pub const ROBOTS_PER_MAP: Limit = Limit { min: 1, max: 1_000, expected: "1 to 1,000 robots per map" };
/// Robots in one world, over all its maps: every robot carries its own particle set, scans and body.
pub const ROBOTS_PER_WORLD: Limit =
    Limit { min: 1, max: 10_000, expected: "1 to 10,000 robots in a world (maps × robots_per_map)" };
/// Maps of one scene or eval map group (PF-net trains on 200 apartments).
pub const MAPS: Limit = Limit { min: 1, max: 1_000, expected: "1 to 1,000 maps" };
/// Particles per robot (paper: 300 / 500 / 3,000; nav2's AMCL at most 2,000 by default).
pub const PARTICLES: Limit = Limit { min: 1, max: 100_000, expected: "1 to 100,000 particles" };
/// Agent steps per episode (paper: 50).
pub const EPISODE_STEPS: Limit = Limit { min: 1, max: 100_000, expected: "1 to 100,000 steps per episode" };
/// Episodes per eval cell (paper: 50).
pub const EPISODES: Limit = Limit { min: 1, max: 100_000, expected: "1 to 100,000 episodes per cell" };
/// Physics steps per agent step (paper: 6).
pub const PHYSICS_SUBSTEPS: Limit =
    Limit { min: 1, max: 100, expected: "1 to 100 physics steps per agent step" };
/// Rays of one scan, simulated or recorded (paper: 228; 2D scanners give up to a few thousand).
pub const BEAMS: Limit = Limit { min: 1, max: 100_000, expected: "1 to 100,000 beams" };
/// Side of a square raster a robot keeps per step (local grid 128, belief crop 50): side² floats each.
pub const RASTER_SIDE: Limit = Limit { min: 1, max: 1_024, expected: "1 to 1,024 cells per side" };
/// Columns of the depth camera (paper: 56).
pub const DEPTH_COLUMNS: Limit = Limit { min: 1, max: 4_096, expected: "1 to 4,096 columns" };
/// Belief crops an agent reads (each 4 × 50 × 50 bytes per transition in the replay buffer).
pub const BELIEF_MODES: Limit = Limit { min: 1, max: 16, expected: "1 to 16 crops" };
/// Past steps whose crops an agent reads beside the present ones (each as many bytes again).
pub const BELIEF_HISTORY: Limit = Limit { min: 0, max: 8, expected: "0 to 8 past steps" };
/// Seeds of a sweep: one job per seed and cell.
pub const SEEDS: Limit = Limit { min: 1, max: 10_000, expected: "1 to 10,000 seeds" };
/// Independent copies of a scene run side by side (`apfn run --worlds`).
pub const WORLDS: Limit = Limit { min: 1, max: 1_024, expected: "1 to 1,024 worlds" };
/// Agent steps of one `apfn run`, whose trajectories are kept in memory until written.
pub const RUN_STEPS: Limit = Limit { min: 1, max: 1_000_000, expected: "1 to 1,000,000 steps" };
/// Worker threads (`--threads`).
pub const THREADS: Limit = Limit { min: 1, max: 1_024, expected: "1 to 1,024 threads" };

/// Every count limit, for the README table and the test that their texts match their numbers.
pub const ALL: [Limit; 14] = [
    ROBOTS_PER_MAP,
    ROBOTS_PER_WORLD,
    MAPS,
    PARTICLES,
    EPISODE_STEPS,
    EPISODES,
    PHYSICS_SUBSTEPS,
    BEAMS,
    RASTER_SIDE,
    DEPTH_COLUMNS,
    SEEDS,
    WORLDS,
    RUN_STEPS,
    THREADS,
];

/// Metres per map cell: the procedural generator's range, which the 0.1 m network map and the
/// robot (radius 0.18 m) are built for.
pub const MAP_RESOLUTION_M: (f64, f64) = (0.005, 0.5);
/// Pixels on either side of a map image (nav2's example maps are at most a few hundred).
pub const MAP_SIDE_PX: u64 = 10_000;
/// Pixels of a map image: the fine grid and each layer derived from it hold a value per cell.
pub const MAP_PIXELS: u64 = 25_000_000;
/// Metres on either side of a map (image side × resolution): the 0.1 m network map grows with it.
pub const MAP_SIDE_M: f64 = 1_000.0;
/// Cells of all the maps of one scene or eval map group together: every map is generated or
/// decoded, and kept with its layers, before the first step (1,000 paper-size apartments take
/// 40 million).
pub const SCENE_MAP_CELLS: u64 = 50_000_000;
/// Metres from the world origin to a map's origin: f32 positions keep millimetres up to here.
pub const MAP_ORIGIN_M: f64 = 10_000.0;

impl Limit {
    /// Whether `n` lies in the range.
    pub fn contains(&self, n: impl TryInto<u64>) -> bool {
        n.try_into().is_ok_and(|n| (self.min..=self.max).contains(&n))
    }

    /// `Err("{field}: expected 1 to 100,000 particles, got 0")` unless `n` is in range: the
    /// message shape of `StepParams::check`.
    pub fn check(&self, field: &str, n: impl TryInto<u64> + Copy + std::fmt::Display) -> Result<(), String> {
        if self.contains(n) { Ok(()) } else { Err(format!("{field}: expected {}, got {n}", self.expected)) }
    }
}

/// `1234567` as `1,234,567`.
pub fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (k, c) in digits.chars().enumerate() {
        if k > 0 && (digits.len() - k).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_name_their_range_and_reject_outside_it() {
        assert_eq!(ROBOTS_PER_MAP.expected, "1 to 1,000 robots per map");
        assert!(ROBOTS_PER_MAP.contains(1_000usize) && !ROBOTS_PER_MAP.contains(1_001usize));
        assert!(!ROBOTS_PER_MAP.contains(0usize), "zero is below every minimum here");
        assert!(!PARTICLES.contains(-1i64), "negative numbers never fit");
        let e = PARTICLES.check("particles", 100_000_000usize).expect_err("too many");
        assert_eq!(e, "particles: expected 1 to 100,000 particles, got 100000000");
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(1_000_000), "1,000,000");
    }

    #[test]
    fn limits_say_the_numbers_they_check() {
        for limit in ALL {
            let range = format!("{} to {} ", thousands(limit.min), thousands(limit.max));
            assert!(limit.expected.starts_with(&range), "{limit:?} should start with {range:?}");
        }
    }
}
