//! Error over time as a figure (`curves/<localizer>_<task>_<split>.png`): one line per policy of
//! a (localizer, task, split) cell group, its mean position error at each step over the cell's
//! episodes (`steps.csv`'s `mean_pos_err_m`), so that where one policy gains on another —
//! the first steps, the convergence, the lost episodes at the end — reads at a glance.

use crate::eval::figure::{FigureError, draw_err, draw_legend, step_chart};
use crate::eval::font::register_sans_serif;
use crate::eval::steps::StepRow;
use crate::eval::table::first_seen;
use image::{Rgb, RgbImage};
use plotters::prelude::*;

const SIZE: (u32, u32) = (1000, 650);
/// Line colours, one per policy in the order the config lists them (Okabe–Ito, then greys).
const PALETTE: [RGBColor; 8] = [
    RGBColor(213, 94, 0),
    RGBColor(0, 114, 178),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
    RGBColor(140, 140, 140),
];

/// The figures of `steps`: one per (localizer, task, split) in the order the rows first name
/// them, with its file name.
pub fn curve_figures(steps: &[StepRow]) -> Result<Vec<(String, RgbImage)>, FigureError> {
    first_seen(steps.iter().map(|row| (row.localizer.as_str(), row.task, row.split.as_str())))
        .into_iter()
        .map(|(localizer, task, split)| {
            let rows: Vec<&StepRow> = steps
                .iter()
                .filter(|r| r.localizer == localizer && r.task == task && r.split == split)
                .collect();
            let name = format!("{localizer}_{}_{}.png", task.name(), file_safe(split));
            let title = format!("{localizer} · {} · {split}: mean position error by step", task.name());
            Ok((name, curve_figure(&rows, &title)?))
        })
        .collect()
}

/// A split label as a file name part ("apartments 300..350" → "apartments_300..350").
fn file_safe(label: &str) -> String {
    label.chars().map(|c| if c.is_alphanumeric() || c == '.' || c == '-' { c } else { '_' }).collect()
}

/// One line per policy of `rows` (all of one cell group), in the order they first appear.
fn curve_figure(rows: &[&StepRow], title: &str) -> Result<RgbImage, FigureError> {
    let policies = first_seen(rows.iter().map(|row| row.policy.as_str()));
    let last = rows.iter().map(|r| r.step).max().unwrap_or(1).max(2) as f32;
    let top = rows.iter().map(|r| r.mean_pos_err_m).filter(|v| v.is_finite()).fold(0.1f32, f32::max) * 1.1;
    let mut canvas = RgbImage::from_pixel(SIZE.0, SIZE.1, Rgb([255, 255, 255]));
    {
        register_sans_serif();
        let root = BitMapBackend::with_buffer(&mut canvas, SIZE).into_drawing_area();
        let area = root.titled(title, ("sans-serif", 28)).map_err(draw_err)?;
        let mut chart = step_chart(&area, last, top, "mean position error (m)")?;
        for (k, policy) in policies.iter().enumerate() {
            let style = PALETTE[k % PALETTE.len()].stroke_width(3);
            let curve =
                rows.iter().filter(|r| r.policy == *policy).map(|r| (r.step as f32, r.mean_pos_err_m));
            chart
                .draw_series(LineSeries::new(curve, style))
                .map_err(draw_err)?
                .label(*policy)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        }
        draw_legend(&mut chart)?;
        root.present().map_err(draw_err)?;
    }
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::episodes::tests::{cell, record};
    use crate::eval::steps::StepRow;

    fn steps(policy: &str, split: &str, errors: &[f32]) -> Vec<StepRow> {
        let row = crate::eval::ResultRow { policy: policy.into(), split: split.into(), ..cell() };
        StepRow::of_cell(&row, &[record(errors)])
    }

    #[test]
    fn one_figure_per_cell_group_with_a_line_per_policy() {
        let rows: Vec<StepRow> = [
            steps("turn", "seen", &[2.0, 1.0, 0.5]),
            steps("goalnav", "seen", &[2.0, 0.5, 0.2]),
            steps("turn", "apartments 300..350", &[1.0, 1.0, 1.0]),
        ]
        .concat();
        let figures = curve_figures(&rows).expect("drawn");
        let names: Vec<&str> = figures.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["mcl_tracking_seen.png", "mcl_tracking_apartments_300..350.png"]);
        let coloured =
            |image: &RgbImage, c: RGBColor| image.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count();
        let (two, one) = (&figures[0].1, &figures[1].1);
        assert!(coloured(two, PALETTE[0]) > 300 && coloured(two, PALETTE[1]) > 300, "both policies drawn");
        assert!(coloured(one, PALETTE[0]) > 300, "the one policy drawn");
        assert_eq!(coloured(one, PALETTE[1]), 0, "no second policy in that group");
    }
}
