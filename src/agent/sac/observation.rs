//! What the agent sees, stored as bytes: the belief crops and the LiDAR grid quantised to u8,
//! the robot state as four floats (and, when the network reads one, the depth strip after it). The policy acts on exactly the bytes the replay buffer keeps,
//! so what it learns from is what it saw.
//!
//! Belief channels are rescaled so that one byte each keeps what matters: free space as is;
//! Σ w per cell on a log scale over four decades (a cell of a 3,000-particle belief can hold
//! 1/3,000 of the mass or all of it); the heading channels divided by Σ w, i.e. the cell's mean
//! heading vector, in [−1, 1].

use crate::agent::Action;
use crate::belief::{BELIEF_CHANNELS, BeliefCrop};
use crate::episode::Episode;
use crate::nn::sac::{STATE_LEN, SacNetConfig};
use crate::sense::{DepthParams, DepthStrip, LocalGrid};

/// Decades of Σ w the log scale spans: weights below 10⁻⁴ read as an empty cell.
const WEIGHT_DECADES: f32 = 4.0;

/// Sizes of one observation's images, from the network they feed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ObservationShape {
    pub belief_cells: usize,
    pub belief_channels: usize,
    pub grid_cells: usize,
    pub depth_columns: usize,
}

impl ObservationShape {
    pub fn of(config: &SacNetConfig) -> Self {
        Self {
            belief_cells: config.belief_cells,
            belief_channels: config.belief_channels,
            grid_cells: config.grid_cells,
            depth_columns: config.depth_columns,
        }
    }

    /// Floats of the vector input: the robot state, then the depth strip.
    pub fn state_len(&self) -> usize {
        STATE_LEN + self.depth_columns
    }

    pub fn belief_len(&self) -> usize {
        self.belief_channels * self.belief_cells * self.belief_cells
    }

    pub fn grid_len(&self) -> usize {
        self.grid_cells * self.grid_cells
    }
}

fn to_byte(unit: f32) -> u8 {
    (unit.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Quantises `crop` into `out` (`shape.belief_len()` bytes); `Err` names the mismatch.
pub fn encode_belief(crop: &BeliefCrop, shape: &ObservationShape, out: &mut [u8]) -> Result<(), String> {
    if crop.cells != shape.belief_cells || crop.values.len() != shape.belief_len() {
        return Err(format!(
            "belief crop: expected {} crop(s) of {} cells (the network's input: (modes + overview) × (1 + history)), \
             got {} values of {} cells; set belief_crop's `cells`, `modes`, `overview_m` and `history` to match",
            shape.belief_channels / BELIEF_CHANNELS,
            shape.belief_cells,
            crop.values.len(),
            crop.cells
        ));
    }
    let area = shape.belief_cells * shape.belief_cells;
    for (values, bytes) in
        crop.values.chunks_exact(BELIEF_CHANNELS * area).zip(out.chunks_exact_mut(BELIEF_CHANNELS * area))
    {
        let (free, rest) = values.split_at(area);
        let (weight, rest) = rest.split_at(area);
        let (cos, sin) = rest.split_at(area);
        for k in 0..area {
            let w = weight[k];
            bytes[k] = to_byte(free[k]);
            bytes[area + k] = if w > 0.0 { to_byte(1.0 + w.log10() / WEIGHT_DECADES) } else { 0 };
            let (c, s) = if w > 0.0 { (cos[k] / w, sin[k] / w) } else { (0.0, 0.0) };
            bytes[2 * area + k] = to_byte(0.5 + 0.5 * c);
            bytes[3 * area + k] = to_byte(0.5 + 0.5 * s);
        }
    }
    Ok(())
}

/// Quantises the occupancy grid (0 occupied, 0.5 unknown, 1 free) into `out`.
pub fn encode_grid(grid: &LocalGrid, shape: &ObservationShape, out: &mut [u8]) -> Result<(), String> {
    if grid.values.len() != shape.grid_len() {
        return Err(format!(
            "local grid: expected {0}×{0} cells (the network's input), got {1} values; set local_grid's `out_cells`",
            shape.grid_cells,
            grid.values.len()
        ));
    }
    out.iter_mut().zip(&grid.values).for_each(|(b, &v)| *b = to_byte(v));
    Ok(())
}

/// v and ω of the last action (normalised), the collision flag, and the fraction of the
/// episode's actions still to come (1 − step/steps: 0 in the last step, which takes no action).
pub fn robot_state(last_action: &Action, collided: bool, episode: &Episode, steps: u32) -> [f32; STATE_LEN] {
    let left = steps.saturating_sub(episode.step) as f32 / steps.max(1) as f32;
    [last_action.linear, last_action.angular, f32::from(u8::from(collided)), left]
}

/// The depth strip as network input, depth / `params.max_m` in [0, 1], into `out`
/// (`shape.depth_columns` values). `Err` names what to schedule or set when the strip is missing
/// or of another width.
pub fn encode_depth(
    strip: Option<&DepthStrip>,
    params: Option<&DepthParams>,
    shape: &ObservationShape,
    out: &mut [f32],
) -> Result<(), String> {
    let n = shape.depth_columns;
    if n == 0 {
        return Ok(());
    }
    let (Some(strip), Some(params)) = (strip, params) else {
        return Err(format!(
            "the policy reads a depth strip of {n} columns; schedule the `depth` step (columns: {n}) before it"
        ));
    };
    if strip.depths_m.len() != n {
        return Err(format!(
            "depth strip: expected {n} columns (the network's input), got {}; set depth's `columns`",
            strip.depths_m.len()
        ));
    }
    out.iter_mut().zip(&strip.depths_m).for_each(|(v, &d)| *v = (d / params.max_m).clamp(0.0, 1.0));
    Ok(())
}

/// Bytes back to network inputs in [0, 1].
pub fn decode(bytes: &[u8], out: &mut [f32]) {
    out.iter_mut().zip(bytes).for_each(|(v, &b)| *v = f32::from(b) / 255.0);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn belief_bytes_keep_free_space_log_weight_and_mean_heading() {
        let shape = ObservationShape { belief_cells: 2, belief_channels: 4, grid_cells: 2, depth_columns: 0 };
        let mut values = vec![0.0; 16];
        values[..4].copy_from_slice(&[1.0, 0.0, 0.5, 1.0]); // free
        values[4..8].copy_from_slice(&[1.0, 1e-2, 0.0, 1e-6]); // Σ w
        values[8..12].copy_from_slice(&[1.0, -1e-2, 0.0, 0.0]); // Σ w cos
        values[12..16].copy_from_slice(&[0.0, 0.0, 0.0, 1e-6]); // Σ w sin
        let crop = BeliefCrop { cells: 2, centres: vec![], values };
        let mut out = vec![0; 16];
        encode_belief(&crop, &shape, &mut out).unwrap();
        assert_eq!(&out[..4], &[255, 0, 128, 255]);
        assert_eq!(&out[4..8], &[255, 128, 0, 0], "log scale: 1 → full, 10⁻² → half, below 10⁻⁴ → empty");
        assert_eq!(&out[8..12], &[255, 0, 128, 128], "mean heading cos: +1, −1, none, 0");
        assert_eq!(out[15], 255, "mean heading sin +1 whatever the weight");
        let wrong = BeliefCrop { cells: 3, centres: vec![], values: vec![0.0; 36] };
        assert!(encode_belief(&wrong, &shape, &mut out).unwrap_err().contains("belief_crop"));
    }

    #[test]
    fn robot_state_counts_agent_steps_left() {
        let a = Action::new(0.5, -1.0);
        assert_eq!(robot_state(&a, true, &Episode { index: 3, step: 1 }, 50), [0.5, -1.0, 1.0, 0.98]);
        assert_eq!(robot_state(&a, false, &Episode { index: 3, step: 50 }, 50)[3], 0.0, "no action left");
    }

    #[test]
    fn depth_input_is_depth_over_range_and_its_absence_names_the_step() {
        let shape = ObservationShape { belief_cells: 2, belief_channels: 4, grid_cells: 2, depth_columns: 3 };
        let params = DepthParams { columns: 3, max_m: 4.0, ..Default::default() };
        let strip = DepthStrip { depths_m: vec![0.1, 2.0, 4.0] };
        let mut out = [9.0; 3];
        encode_depth(Some(&strip), Some(&params), &shape, &mut out).unwrap();
        assert_eq!(out, [0.025, 0.5, 1.0]);
        let err = encode_depth(None, None, &shape, &mut out).unwrap_err();
        assert!(err.contains("`depth` step") && err.contains("columns: 3"), "{err}");
        let wide = DepthStrip { depths_m: vec![1.0; 56] };
        let err = encode_depth(Some(&wide), Some(&params), &shape, &mut out).unwrap_err();
        assert!(err.contains("expected 3 columns") && err.contains("got 56"), "{err}");
        let lidar_only = ObservationShape { depth_columns: 0, ..shape };
        assert_eq!(encode_depth(None, None, &lidar_only, &mut []), Ok(()), "no depth input, nothing needed");
    }
}
