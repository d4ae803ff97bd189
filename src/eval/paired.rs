//! Paired comparisons between policies (`paired.md`). Under common random numbers the k-th
//! episode of every policy in one (localizer, task, split) cell starts from the same pose with the
//! same initial particles, so the per-episode difference of two policies' errors cancels the
//! spread between start poses and apartments that dominates each cell's own variance. Per cell
//! and policy: the mean difference of its mean position error to the best *other* policy of the
//! cell, with a 95 % interval (normal approximation over the paired episodes, which are
//! independent draws). Episodes whose start poses differ are never paired.

use crate::eval::episodes::EpisodeRow;
use crate::particles::Task;
use serde::Serialize;
use std::fmt::Write;

/// 97.5 % quantile of the standard normal: the half-width of a 95 % interval in standard errors.
const Z_95: f64 = 1.959_964;

/// One policy of one cell against the cell's best other policy.
#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct PairedRow {
    pub localizer: String,
    pub task: Task,
    pub split: String,
    pub policy: String,
    /// Mean position error over the policy's episodes, cm.
    pub mean_cm: f64,
    /// The other policy of the cell with the lowest mean error.
    pub other: String,
    /// Episodes paired with `other` (same index, same start pose).
    pub pairs: usize,
    /// Mean of (this policy's − the other's) error over the pairs, cm, and its 95 % interval.
    pub diff_cm: f64,
    pub diff_low_cm: f64,
    pub diff_high_cm: f64,
}

/// Every policy of every cell against its cell's best other policy; cells with one policy give
/// no row.
pub fn paired_rows(episodes: &[EpisodeRow]) -> Vec<PairedRow> {
    let mut cells: Vec<(&str, Task, &str)> = Vec::new();
    for e in episodes {
        let cell = (e.localizer.as_str(), e.task, e.split.as_str());
        if !cells.contains(&cell) {
            cells.push(cell);
        }
    }
    let mut rows = Vec::new();
    for (localizer, task, split) in cells {
        let in_cell: Vec<&EpisodeRow> = episodes
            .iter()
            .filter(|e| e.localizer == localizer && e.task == task && e.split == split)
            .collect();
        let mut policies: Vec<(&str, f64)> = Vec::new();
        for e in &in_cell {
            if !policies.iter().any(|(p, _)| *p == e.policy) {
                policies.push((&e.policy, mean_cm(in_cell.iter().filter(|o| o.policy == e.policy).copied())));
            }
        }
        for &(policy, mean) in &policies {
            let best_other = policies.iter().filter(|(p, _)| *p != policy).min_by(|a, b| a.1.total_cmp(&b.1));
            let Some(&(other, _)) = best_other else { continue };
            let diffs = paired_differences_cm(&in_cell, policy, other);
            let (diff, half) = mean_and_half_width(&diffs);
            rows.push(PairedRow {
                localizer: localizer.to_owned(),
                task,
                split: split.to_owned(),
                policy: policy.to_owned(),
                mean_cm: mean,
                other: other.to_owned(),
                pairs: diffs.len(),
                diff_cm: diff,
                diff_low_cm: diff - half,
                diff_high_cm: diff + half,
            });
        }
    }
    rows
}

fn mean_cm<'a>(episodes: impl Iterator<Item = &'a EpisodeRow>) -> f64 {
    let errors: Vec<f64> = episodes.map(|e| f64::from(e.mean_pos_err_m) * 100.0).collect();
    errors.iter().sum::<f64>() / errors.len().max(1) as f64
}

/// (a's − b's) mean position error of every episode index both ran from the same start pose, cm.
fn paired_differences_cm(cell: &[&EpisodeRow], a: &str, b: &str) -> Vec<f64> {
    let start = |e: &EpisodeRow| (e.start_x, e.start_y, e.start_yaw);
    cell.iter()
        .filter(|e| e.policy == a)
        .filter_map(|ea| {
            let eb = cell.iter().find(|e| e.policy == b && e.episode == ea.episode)?;
            (start(ea) == start(eb)).then(|| f64::from(ea.mean_pos_err_m - eb.mean_pos_err_m) * 100.0)
        })
        .collect()
}

/// The mean and the 95 % half-width (z · s / √n; NaN below two values).
fn mean_and_half_width(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return (mean, f64::NAN);
    }
    let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, Z_95 * (variance / n).sqrt())
}

/// One table per (localizer, task, split): policy, its mean error, the best other policy and the
/// paired difference with its interval; "yes" where the interval excludes 0.
pub fn paired_markdown(rows: &[PairedRow]) -> String {
    let mut out = String::from(
        "Paired comparisons: each policy's mean position error against the best other policy of its \
         cell, over episodes that start alike (common random numbers). Δ = this policy − the other, cm, \
         with a 95 % interval (normal approximation); negative is better.\n",
    );
    let mut current = None;
    for r in rows {
        let cell = (r.localizer.as_str(), r.task, r.split.as_str());
        if current != Some(cell) {
            current = Some(cell);
            let _ = write!(
                out,
                "\n### {} · {} · {}\n\n| policy | mean (cm) | vs | pairs | Δ (cm) | 95 % interval | excludes 0 |\n|---|---|---|---|---|---|---|\n",
                r.localizer,
                r.task.name(),
                r.split
            );
        }
        let clear = if r.diff_low_cm > 0.0 || r.diff_high_cm < 0.0 { "yes" } else { "no" };
        let _ = writeln!(
            out,
            "| {} | {:.1} | {} | {} | {:+.1} | [{:+.1}, {:+.1}] | {clear} |",
            r.policy, r.mean_cm, r.other, r.pairs, r.diff_cm, r.diff_low_cm, r.diff_high_cm
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(policy: &str, episode: usize, start_x: f32, error_m: f32) -> EpisodeRow {
        EpisodeRow {
            localizer: "mcl".into(),
            policy: policy.into(),
            task: Task::Global,
            split: "unseen".into(),
            episode,
            start_x,
            start_y: 0.0,
            start_yaw: 0.0,
            final_x: 0.0,
            final_y: 0.0,
            final_yaw: 0.0,
            estimate_x: 0.0,
            estimate_y: 0.0,
            estimate_yaw: 0.0,
            mean_pos_err_m: error_m,
            final_pos_err_m: error_m,
            final_orient_err_rad: 0.0,
            success: true,
            collisions: 0,
        }
    }

    #[test]
    fn paired_differences_cancel_the_spread_between_starts() {
        // Starts vary from 0.1 m to 4 m of error, but b is always 0.1 m worse than a: the paired
        // difference is exactly −10 cm with no spread, though the cells' own spreads are huge.
        let starts = [0.1f32, 4.0, 1.0, 2.5];
        let mut episodes = Vec::new();
        for (k, &e) in starts.iter().enumerate() {
            episodes.push(episode("a", k, k as f32, e));
            episodes.push(episode("b", k, k as f32, e + 0.1));
        }
        let rows = paired_rows(&episodes);
        let a = rows.iter().find(|r| r.policy == "a").expect("a compared");
        assert_eq!((a.other.as_str(), a.pairs), ("b", 4));
        assert!((a.diff_cm + 10.0).abs() < 1e-3, "{a:?}");
        assert!((a.diff_high_cm - a.diff_low_cm).abs() < 1e-3, "no spread in the differences: {a:?}");
        assert!((a.mean_cm - 190.0).abs() < 1e-3, "mean of 10, 400, 100, 250 cm: {}", a.mean_cm);
        let md = paired_markdown(&rows);
        assert!(md.contains("| a | 190.0 | b | 4 | -10.0 | [-10.0, -10.0] | yes |"), "{md}");
    }

    #[test]
    fn the_interval_is_z_standard_errors_and_unlike_starts_are_not_paired() {
        // Differences −0.1, +0.1, −0.3 m → mean −10 cm, s = 20 cm, n = 3: half-width 1.96 · 20 / √3.
        let episodes = vec![
            episode("a", 0, 0.0, 1.0),
            episode("b", 0, 0.0, 1.1),
            episode("a", 1, 1.0, 1.0),
            episode("b", 1, 1.0, 0.9),
            episode("a", 2, 2.0, 1.0),
            episode("b", 2, 2.0, 1.3),
            episode("a", 3, 3.0, 1.0),
            episode("b", 3, 9.0, 5.0), // another start: never paired
        ];
        let rows = paired_rows(&episodes);
        let a = rows.iter().find(|r| r.policy == "a").expect("a compared");
        assert_eq!(a.pairs, 3, "the episode with another start is left out");
        let half = Z_95 * 20.0 / 3f64.sqrt();
        assert!((a.diff_cm + 10.0).abs() < 1e-3 && (a.diff_high_cm - (-10.0 + half)).abs() < 1e-3, "{a:?}");
        assert_eq!(paired_rows(&episodes[..1]), vec![], "one policy: nothing to compare");
    }
}
