//! The paper-style figure of one episode: left, the map around the episode (north up) with the
//! particles after the first filter update, the true path drawn over the estimate, their start
//! and final poses, the final error and a scale bar; right, position and heading error over the
//! episode's steps; below, when the schedule made one, the belief crop the agent read at a few
//! steps.

use crate::episode::{CropSnapshot, EpisodeLog, EpisodeRecord, SUCCESS_RADIUS_M, succeeded};
use crate::eval::font::register_sans_serif;
use crate::eval::row::ResultRow;
use crate::world::map::render;
use crate::world::{OccupancyMap, Pose2};
use image::{ImageFormat, Rgb, RgbImage, imageops};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf32;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::io::Cursor;

/// Figure size (pixels), the title strip's height and the map panel: left, top, width, height.
const SIZE: (u32, u32) = (1400, 700);
const TITLE_H: i32 = 50;
const MAP_PANEL: (i32, i32, u32, u32) = (15, 55, 670, 560);
/// The strip of belief crops under the panels: its height, pixels per crop cell, and the top
/// of the crops within it.
const CROP_STRIP_H: u32 = 300;
const CROP_PX: u32 = 4;
const CROP_TOP: i32 = 45;
/// Space shown around the episode's trajectories and particles (metres).
const MARGIN_M: f32 = 2.0;
const TRUTH: RGBColor = RGBColor(0, 150, 60);
const ESTIMATE: RGBColor = RGBColor(235, 95, 0);
const PARTICLE: RGBColor = RGBColor(40, 70, 220);
/// Labels, legends and axes; the title is larger.
const TEXT: (&str, u32) = ("sans-serif", 27);

#[derive(Debug, thiserror::Error)]
pub enum FigureError {
    #[error("episode {episode} logged no poses: nothing to draw")]
    Empty { episode: u32 },
    #[error("drawing the figure: {0}")]
    Draw(String),
    #[error("encoding the figure as PNG: {0}")]
    Encode(#[from] image::ImageError),
}

pub(super) fn draw_err(e: impl std::error::Error) -> FigureError {
    FigureError::Draw(e.to_string())
}

/// "mcl · turn · tracking · seen · episode 3".
pub fn figure_title(row: &ResultRow, k: usize) -> String {
    format!("{} · {} · {} · {} · episode {k}", row.localizer, row.policy, row.task.name(), row.split)
}

/// "mcl_turn_tracking_seen_ep3.png".
pub fn figure_file_name(row: &ResultRow, k: usize) -> String {
    format!("{}_{}_{}_{}_ep{k}.png", row.localizer, row.policy, row.task.name(), row.split)
}

pub fn encode_png(image: &RgbImage) -> Result<Vec<u8>, FigureError> {
    let mut png = Vec::new();
    image.write_to(&mut Cursor::new(&mut png), ImageFormat::Png)?;
    Ok(png)
}

/// Where the map crop lands: grid cells [i0, i1) × [j0, j1) scaled by `px_per_cell`, its top-left
/// corner at (left, top).
struct View {
    i0: u32,
    i1: u32,
    j0: u32,
    j1: u32,
    px_per_cell: f32,
    left: i32,
    top: i32,
}

impl View {
    /// The crop holding every point plus the margin, clamped to the map, fitted to the panel.
    fn fit(map: &OccupancyMap, points: impl Iterator<Item = (f32, f32)>) -> View {
        let margin = MARGIN_M / map.resolution_m;
        let (mut lo, mut hi) = ((f32::MAX, f32::MAX), (f32::MIN, f32::MIN));
        for (gx, gy) in
            points.map(|(x, y)| map.world_to_grid(x, y)).filter(|p| p.0.is_finite() && p.1.is_finite())
        {
            (lo, hi) = ((lo.0.min(gx), lo.1.min(gy)), (hi.0.max(gx), hi.1.max(gy)));
        }
        let clamp = |v: f32, n: usize| v.clamp(0.0, n as f32) as u32;
        let (mut i0, mut i1) =
            (clamp((lo.0 - margin).floor(), map.width), clamp((hi.0 + margin).ceil(), map.width));
        let (mut j0, mut j1) =
            (clamp((lo.1 - margin).floor(), map.height), clamp((hi.1 + margin).ceil(), map.height));
        if i1 <= i0 || j1 <= j0 {
            (i0, i1, j0, j1) = (0, map.width as u32, 0, map.height as u32); // all points off the map
        }
        let (x, y, w, h) = MAP_PANEL;
        let px_per_cell = (w as f32 / (i1 - i0) as f32).min(h as f32 / (j1 - j0) as f32);
        let (sw, sh) = (((i1 - i0) as f32 * px_per_cell) as i32, ((j1 - j0) as f32 * px_per_cell) as i32);
        View { i0, i1, j0, j1, px_per_cell, left: x + (w as i32 - sw) / 2, top: y + (h as i32 - sh) / 2 }
    }

    fn size(&self) -> (u32, u32) {
        let scaled = |n: u32| (n as f32 * self.px_per_cell) as u32;
        (scaled(self.i1 - self.i0), scaled(self.j1 - self.j0))
    }

    fn pixel(&self, map: &OccupancyMap, x: f32, y: f32) -> (i32, i32) {
        let (gx, gy) = map.world_to_grid(x, y);
        let k = self.px_per_cell;
        (self.left + ((gx - self.i0 as f32) * k) as i32, self.top + ((self.j1 as f32 - gy) * k) as i32)
    }

    /// A triangle pointing along the pose's heading (image y grows down).
    fn arrow(&self, map: &OccupancyMap, pose: &Pose2) -> Vec<(i32, i32)> {
        let (cx, cy) = self.pixel(map, pose.x, pose.y);
        let (s, c) = (pose.yaw - map.origin.yaw).sin_cos();
        let at =
            |ahead: f32, side: f32| (cx + (c * ahead + s * side) as i32, cy + (-s * ahead + c * side) as i32);
        vec![at(16.0, 0.0), at(-8.0, 8.0), at(-8.0, -8.0)]
    }
}

/// Draws one episode on its map; `title` goes above both panels.
pub fn episode_figure(
    map: &OccupancyMap,
    record: &EpisodeRecord,
    title: &str,
) -> Result<RgbImage, FigureError> {
    let log = &record.log;
    if log.truth.is_empty() || log.estimates.is_empty() {
        return Err(FigureError::Empty { episode: record.episode });
    }
    let poses = log.truth.iter().chain(&log.estimates).map(|p| (p.x, p.y));
    let view = View::fit(map, poses.chain(log.first_particles.iter().copied()));
    let height = SIZE.1 + if log.crops.is_empty() { 0 } else { CROP_STRIP_H };
    let mut canvas = RgbImage::from_pixel(SIZE.0, height, Rgb([255, 255, 255]));
    let background = render(map, None);
    let crop = imageops::crop_imm(
        &background,
        view.i0,
        map.height as u32 - view.j1,
        view.i1 - view.i0,
        view.j1 - view.j0,
    );
    let (w, h) = view.size();
    let scaled = imageops::resize(&crop.to_image(), w, h, imageops::FilterType::Nearest);
    imageops::replace(&mut canvas, &scaled, view.left as i64, view.top as i64);
    {
        register_sans_serif();
        let root = BitMapBackend::with_buffer(&mut canvas, (SIZE.0, height)).into_drawing_area();
        let (main, _) = root.split_vertically(SIZE.1);
        draw_map_overlay(&main, map, &view, log)?;
        let centred = Pos::new(HPos::Center, VPos::Center);
        let font = ("sans-serif", 40).into_font().color(&BLACK).pos(centred);
        main.draw(&Text::new(title, (SIZE.0 as i32 / 2, TITLE_H / 2 + 5), font)).map_err(draw_err)?;
        let (_, right) = main.split_horizontally(MAP_PANEL.0 as u32 + MAP_PANEL.2 + 15);
        let (_, right) = right.split_vertically(TITLE_H);
        let (top, bottom) = right.split_vertically((SIZE.1 - TITLE_H as u32) / 2);
        let pos: Vec<f32> = log.errors.iter().map(|e| e.pos_err_m).collect();
        let yaw: Vec<f32> = log.errors.iter().map(|e| e.orient_err_rad).collect();
        error_chart(&top, &pos, "position error (m)", Some(SUCCESS_RADIUS_M))?;
        error_chart(&bottom, &yaw, "|heading error| (rad)", None)?;
        draw_crop_labels(&root, &log.crops)?;
        root.present().map_err(draw_err)?;
    }
    // After the overlay, whose masks white out everything under the map panel.
    for (k, snapshot) in log.crops.iter().enumerate() {
        let (x, y) = crop_corner(k, log.crops.len(), snapshot.cells);
        imageops::replace(&mut canvas, &crop_image(snapshot), x as i64, y as i64);
    }
    Ok(canvas)
}

/// Top-left pixel of the `k`-th of `count` crops of `cells`² in the strip, centred in equal slots.
fn crop_corner(k: usize, count: usize, cells: usize) -> (i32, i32) {
    let slot = (SIZE.0 as i32 - 2 * MAP_PANEL.0) / count.max(1) as i32;
    let side = (cells as u32 * CROP_PX) as i32;
    (MAP_PANEL.0 + k as i32 * slot + (slot - side) / 2, SIZE.1 as i32 + CROP_TOP)
}

/// A crop as the figure shows it: free space light, obstacles and unknown dark, particle weight
/// blending into blue (the heaviest cell fully blue; a square root shows light modes beside a
/// heavy one), `CROP_PX` pixels per cell.
fn crop_image(snapshot: &CropSnapshot) -> RgbImage {
    let n = snapshot.cells as u32;
    let image = RgbImage::from_fn(n, n, |col, row| {
        let cell = (row * n + col) as usize;
        let grey = 60.0 + 180.0 * f32::from(snapshot.free[cell]) / 255.0;
        let alpha = (f32::from(snapshot.weight[cell]) / 255.0).sqrt();
        let blend = |c: u8| (grey * (1.0 - alpha) + f32::from(c) * alpha).round() as u8;
        Rgb([blend(PARTICLE.0), blend(PARTICLE.1), blend(PARTICLE.2)])
    });
    imageops::resize(&image, n * CROP_PX, n * CROP_PX, imageops::FilterType::Nearest)
}

/// The strip's heading; around each crop a frame, ticks at the estimate and its step.
fn draw_crop_labels<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    crops: &[CropSnapshot],
) -> Result<(), FigureError> {
    let Some(first) = crops.first() else { return Ok(()) };
    let left = Pos::new(HPos::Left, VPos::Center);
    let heading = "the agent's belief crop, centred on the estimate (ticks), heading up: free space light, particle weight blue";
    let at = (MAP_PANEL.0 + 5, SIZE.1 as i32 + CROP_TOP / 2);
    root.draw(&Text::new(heading, at, TEXT.into_font().color(&BLACK).pos(left))).map_err(draw_err)?;
    let side = (first.cells as u32 * CROP_PX) as i32;
    for (k, snapshot) in crops.iter().enumerate() {
        let (x, y) = crop_corner(k, crops.len(), snapshot.cells);
        root.draw(&Rectangle::new([(x - 1, y - 1), (x + side, y + side)], BLACK.stroke_width(1)))
            .map_err(draw_err)?;
        // Ticks outside the frame point at the centre (the estimate), leaving its cells visible.
        let (cx, cy) = (x + side / 2, y + side / 2);
        for tick in [[(cx, y - 10), (cx, y - 2)], [(cx, y + side + 1), (cx, y + side + 9)]]
            .into_iter()
            .chain([[(x - 10, cy), (x - 2, cy)], [(x + side + 1, cy), (x + side + 9, cy)]])
        {
            root.draw(&PathElement::new(tick.to_vec(), ESTIMATE.stroke_width(2))).map_err(draw_err)?;
        }
        let centred = Pos::new(HPos::Center, VPos::Center);
        let label = Text::new(
            format!("step {}", snapshot.step),
            (cx, y + side + 22),
            TEXT.into_font().color(&BLACK).pos(centred),
        );
        root.draw(&label).map_err(draw_err)?;
    }
    Ok(())
}

/// Particles, paths, start and final poses (clipped to the map crop), a frame, the legend and a
/// scale bar.
fn draw_map_overlay<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    map: &OccupancyMap,
    view: &View,
    log: &EpisodeLog,
) -> Result<(), FigureError> {
    for &(x, y) in &log.first_particles {
        root.draw(&Circle::new(view.pixel(map, x, y), 2, PARTICLE.mix(0.45).filled())).map_err(draw_err)?;
    }
    // The estimate first and wide, the truth over it and thin: where they agree, both show.
    let paths = [(&log.estimates, ESTIMATE, 6), (&log.truth, TRUTH, 2)];
    for (poses, colour, width) in paths {
        // Segment by segment with round joints: plotters' mitred joins of one wide path shoot
        // spikes across the figure where a robot turning on the spot reverses its path.
        let path: Vec<(i32, i32)> = poses.iter().map(|p| view.pixel(map, p.x, p.y)).collect();
        for segment in path.windows(2) {
            root.draw(&PathElement::new(segment.to_vec(), colour.stroke_width(width))).map_err(draw_err)?;
        }
        for &joint in &path {
            root.draw(&Circle::new(joint, width / 2, colour.filled())).map_err(draw_err)?;
        }
    }
    for (poses, colour, _) in paths {
        let (Some(first), Some(last)) = (poses.first(), poses.last()) else { continue };
        start_marker(root, view.arrow(map, first), colour)?;
        root.draw(&Polygon::new(view.arrow(map, last), colour.filled())).map_err(draw_err)?;
        let outline: Vec<_> = view.arrow(map, last).into_iter().cycle().take(4).collect();
        root.draw(&PathElement::new(outline, BLACK.stroke_width(1))).map_err(draw_err)?;
    }
    // Clip: white out the left panel around the map crop (estimates may leave the map).
    let (w, h) = view.size();
    let (l, t, r, b) = (view.left, view.top, view.left + w as i32, view.top + h as i32);
    // Down to the figure's bottom: a path leaving the map must not cross the belief crops' strip.
    let (panel_r, panel_b) = (MAP_PANEL.0 + MAP_PANEL.2 as i32 + 14, (SIZE.1 + CROP_STRIP_H) as i32);
    for mask in [
        [(0, 0), (panel_r, t - 1)],
        [(0, b), (panel_r, panel_b)],
        [(0, t), (l - 1, b)],
        [(r, t), (panel_r, b)],
    ] {
        root.draw(&Rectangle::new(mask, WHITE.filled())).map_err(draw_err)?;
    }
    root.draw(&Rectangle::new([(l - 1, t - 1), (r, b)], BLACK.stroke_width(1))).map_err(draw_err)?;
    final_error_label(root, (l, t), &log.errors)?;
    scale_bar(root, map, view, (r, b))?;
    // Legend: two rows under the map.
    let (x, y) = (MAP_PANEL.0 + 5, MAP_PANEL.1 + MAP_PANEL.3 as i32 + 22);
    let label = |text: &str, at: (i32, i32)| {
        root.draw(&Text::new(
            text.to_owned(),
            at,
            TEXT.into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(draw_err)
    };
    for (k, (text, colour, width)) in
        [("true path", TRUTH, 2), ("estimate", ESTIMATE, 6)].into_iter().enumerate()
    {
        let x = x + 170 * k as i32;
        root.draw(&PathElement::new(vec![(x, y), (x + 40, y)], colour.stroke_width(width)))
            .map_err(draw_err)?;
        label(text, (x + 50, y))?;
    }
    let marker = |dx: i32| vec![(x + dx + 16, y), (x + dx, y - 8), (x + dx, y + 8)];
    start_marker(root, marker(340), BLACK)?;
    label("start", (x + 368, y))?;
    root.draw(&Polygon::new(marker(460), BLACK.filled())).map_err(draw_err)?;
    label("final pose", (x + 488, y))?;
    let y = y + 32;
    for dx in [4, 12, 9, 18, 25, 31] {
        root.draw(&Circle::new((x + dx, y + (dx % 3) * 3 - 3), 2, PARTICLE.mix(0.6).filled()))
            .map_err(draw_err)?;
    }
    label(&particles_label(log), (x + 50, y))
}

/// "particles at step 1", and how many of how many are drawn when the set was subsampled.
fn particles_label(log: &EpisodeLog) -> String {
    let (shown, total) = (log.first_particles.len(), log.first_particle_count);
    if shown < total {
        format!("particles at step 1 ({shown} of {total} drawn)")
    } else {
        "particles at step 1".into()
    }
}

/// A white box with `lines` of text, its top-left corner at `at`.
fn boxed_text<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    lines: &[String],
) -> Result<(), FigureError> {
    let (x, y) = at;
    let style = TEXT.into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
    let mut widest = 0;
    for line in lines {
        widest = widest.max(root.estimate_text_size(line, &style).map_err(draw_err)?.0 as i32);
    }
    let (width, bottom) = (16 + widest, y + 8 + 28 * lines.len() as i32);
    root.draw(&Rectangle::new([(x, y), (x + width, bottom)], WHITE.mix(0.85).filled())).map_err(draw_err)?;
    root.draw(&Rectangle::new([(x, y), (x + width, bottom)], BLACK.stroke_width(1))).map_err(draw_err)?;
    for (k, line) in lines.iter().enumerate() {
        root.draw(&Text::new(line.clone(), (x + 8, y + 18 + 28 * k as i32), style.clone()))
            .map_err(draw_err)?;
    }
    Ok(())
}

/// The final position and heading error and the episode's verdict, in the map's top-left corner.
fn final_error_label<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    top_left: (i32, i32),
    errors: &[crate::episode::StepError],
) -> Result<(), FigureError> {
    let Some(last) = errors.last() else { return Ok(()) };
    let verdict = if succeeded(errors) { "success" } else { "failure" };
    let lines = [
        format!("final error {:.1} cm, {:.2} rad", last.pos_err_m * 100.0, last.orient_err_rad),
        format!("{verdict}: < {SUCCESS_RADIUS_M} m in the last 25 %"),
    ];
    boxed_text(root, (top_left.0 + 6, top_left.1 + 6), &lines)
}

/// A bar of 1, 2, 5, 10 or 20 m (the first at least 60 px long) in the map's bottom-right corner.
fn scale_bar<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    map: &OccupancyMap,
    view: &View,
    bottom_right: (i32, i32),
) -> Result<(), FigureError> {
    let bar_m = [1.0f32, 2.0, 5.0, 10.0]
        .into_iter()
        .find(|m| m / map.resolution_m * view.px_per_cell >= 60.0)
        .unwrap_or(20.0);
    let bar_px = (bar_m / map.resolution_m * view.px_per_cell) as i32;
    let (r, b) = (bottom_right.0 - 10, bottom_right.1 - 12);
    let left = r - bar_px - 70;
    root.draw(&Rectangle::new([(left, b - 26), (r + 6, b + 8)], WHITE.mix(0.85).filled()))
        .map_err(draw_err)?;
    root.draw(&PathElement::new(vec![(r - bar_px, b - 6), (r, b - 6)], BLACK.stroke_width(4)))
        .map_err(draw_err)?;
    let style = TEXT.into_font().color(&BLACK).pos(Pos::new(HPos::Right, VPos::Center));
    root.draw(&Text::new(format!("{bar_m} m"), (r - bar_px - 8, b - 8), style)).map_err(draw_err)
}

/// A hollow heading triangle: white inside, coloured outline.
fn start_marker<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    corners: Vec<(i32, i32)>,
    colour: RGBColor,
) -> Result<(), FigureError> {
    root.draw(&Polygon::new(corners.clone(), WHITE.filled())).map_err(draw_err)?;
    let outline: Vec<_> = corners.iter().chain(corners.first()).copied().collect();
    root.draw(&PathElement::new(outline, colour.stroke_width(3))).map_err(draw_err)
}

/// One error curve over steps 1…T, with a dashed line at `threshold` if given.
fn error_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    values: &[f32],
    y_desc: &str,
    threshold: Option<f32>,
) -> Result<(), FigureError> {
    let last = (values.len() as f32).max(2.0);
    let top = values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(threshold.unwrap_or(0.0) * 1.5, f32::max)
        .max(0.1)
        * 1.1;
    let mut chart = step_chart(area, last, top, y_desc)?;
    let curve = values.iter().enumerate().map(|(k, v)| (k as f32 + 1.0, *v));
    let style = RGBColor(180, 30, 30).stroke_width(3);
    chart
        .draw_series(LineSeries::new(curve, style))
        .map_err(draw_err)?
        .label(y_desc.split(" (").next().unwrap_or(y_desc).trim_matches('|'))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
    if let Some(r) = threshold {
        let dashed = BLACK.stroke_width(2);
        chart
            .draw_series(DashedLineSeries::new([(1.0, r), (last, r)], 10, 7, dashed))
            .map_err(draw_err)?
            .label(format!("success radius {r} m"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], dashed));
    }
    draw_legend(&mut chart)
}

/// A chart over steps 1…`last` and errors 0…`top`, its axes and grid drawn.
pub(super) fn step_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    last: f32,
    top: f32,
    y_desc: &str,
) -> Result<StepChart<'a, DB>, FigureError> {
    let mut chart = ChartBuilder::on(area)
        .margin(15)
        .x_label_area_size(55)
        .y_label_area_size(100)
        .build_cartesian_2d(1f32..last, 0f32..top)
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc(y_desc)
        .x_labels(8)
        .y_labels(6)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y:.*}", if top < 0.5 { 2 } else { 1 }))
        .label_style(TEXT)
        .axis_desc_style(TEXT)
        .light_line_style(RGBColor(236, 236, 236))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()
        .map_err(draw_err)?;
    Ok(chart)
}

/// What [`step_chart`] returns: plotters' chart on f32 steps × f32 errors.
pub(super) type StepChart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf32, RangedCoordf32>>;

/// The labelled series' legend, top right.
pub(super) fn draw_legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut StepChart<'a, DB>,
) -> Result<(), FigureError> {
    chart
        .configure_series_labels()
        .label_font(TEXT)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{EpisodeLog, StepError};
    use crate::testing::tiny_room;
    use bevy::prelude::Entity;

    /// Five steps east along y = 0.5 m in the tiny room; the estimate trails 0.2 m behind.
    fn record() -> EpisodeRecord {
        let truth: Vec<Pose2> = (0..5).map(|k| Pose2 { x: 0.4 + 0.2 * k as f32, y: 0.5, yaw: 0.0 }).collect();
        let estimates: Vec<Pose2> =
            truth.iter().map(|p| Pose2 { x: p.x - 0.2, y: p.y + 0.1, yaw: 0.3 }).collect();
        let errors = truth.iter().zip(&estimates).map(|(t, e)| StepError::between(e, t)).collect();
        let first_particles = (0..50).map(|k| (0.3 + 0.02 * k as f32, 0.9)).collect();
        let log = EpisodeLog {
            errors,
            truth,
            estimates,
            first_particles,
            first_particle_count: 200,
            collisions: 0,
            crops: Vec::new(),
        };
        EpisodeRecord { robot: Entity::PLACEHOLDER, map: Entity::PLACEHOLDER, episode: 3, log }
    }

    fn near(img: &RgbImage, (cx, cy): (i32, i32), r: i32, want: impl Fn(&Rgb<u8>) -> bool) -> bool {
        (cx - r..=cx + r).flat_map(|x| (cy - r..=cy + r).map(move |y| (x, y))).any(|(x, y)| {
            x >= 0
                && y >= 0
                && (x as u32) < img.width()
                && (y as u32) < img.height()
                && want(img.get_pixel(x as u32, y as u32))
        })
    }

    #[test]
    fn episode_figure_draws_paths_on_the_map_and_the_error_curves() {
        let (map, record) = (tiny_room(), record());
        let img = episode_figure(&map, &record, "mcl · turn · tracking · seen · episode 3").expect("figure");
        assert_eq!(img.dimensions(), SIZE, "fixed figure size");
        let view = View::fit(&map, record.log.truth.iter().map(|p| (p.x, p.y)));
        assert_eq!(
            (view.i0, view.i1, view.j0, view.j1),
            (0, 20, 0, 15),
            "2 m margin clamps to the whole 2 × 1.5 m room"
        );
        let green = |p: &Rgb<u8>| p.0 == [TRUTH.0, TRUTH.1, TRUTH.2];
        let mid = &record.log.truth[2];
        assert!(
            near(&img, view.pixel(&map, mid.x, mid.y), 2, green),
            "true path is green where its middle pose maps"
        );
        let (fx, fy) = view.pixel(&map, 1.0, 1.2);
        assert!(!near(&img, (fx, fy), 3, green), "no green far from the path, at ({fx}, {fy})");
        let wall = view.pixel(&map, 0.05, 0.05);
        assert_eq!(
            img.get_pixel(wall.0 as u32 + 2, wall.1 as u32 - 2).0,
            [0, 0, 0],
            "the map's bottom-left wall is black (the final-error box covers the top-left)"
        );
        let curve = |p: &Rgb<u8>| p.0 == [180, 30, 30];
        let right_panel = (MAP_PANEL.0 as u32 + MAP_PANEL.2 + 15)..SIZE.0;
        let drawn = right_panel
            .flat_map(|x| (0..SIZE.1).map(move |y| (x, y)))
            .filter(|&(x, y)| curve(img.get_pixel(x, y)))
            .count();
        assert!(drawn > 200, "both error curves are drawn in the right panel ({drawn} curve pixels)");
        let orange = |p: &Rgb<u8>| p.0 == [ESTIMATE.0, ESTIMATE.1, ESTIMATE.2];
        let first = &record.log.truth[1];
        assert!(
            !near(&img, view.pixel(&map, first.x, first.y), 0, orange),
            "the true path is drawn over the estimate, not hidden under it"
        );
        assert_eq!(
            particles_label(&record.log),
            "particles at step 1 (50 of 200 drawn)",
            "subsampling is said"
        );
        let png = encode_png(&img).expect("encode");
        assert!(image::load_from_memory(&png).is_ok(), "PNG decodes");
    }

    #[test]
    fn belief_crops_are_drawn_in_a_strip_under_the_panels() {
        let mut record = record();
        let cells = 10;
        let snapshot = |step: u32, heavy: usize| {
            let mut weight = vec![0u8; cells * cells];
            weight[heavy] = 255;
            CropSnapshot { step, cells, free: vec![255; cells * cells], weight }
        };
        record.log.crops = vec![snapshot(1, 0), snapshot(5, cells * cells - 1)];
        let img = episode_figure(&tiny_room(), &record, "t").expect("figure");
        assert_eq!(img.dimensions(), (SIZE.0, SIZE.1 + CROP_STRIP_H), "the strip extends the figure");
        let blue = |p: &Rgb<u8>| p.0 == [PARTICLE.0, PARTICLE.1, PARTICLE.2];
        let light = |p: &Rgb<u8>| p.0 == [240, 240, 240];
        let side = (cells as u32 * CROP_PX) as i32;
        let (x0, y0) = crop_corner(0, 2, cells);
        let (x1, y1) = crop_corner(1, 2, cells);
        let cell_centre = |(x, y): (i32, i32), i: i32, j: i32| (x + i * 4 + 2, y + j * 4 + 2);
        assert!(near(&img, cell_centre((x0, y0), 0, 0), 0, blue), "first crop: heaviest cell top-left");
        assert!(near(&img, cell_centre((x1, y1), 9, 9), 0, blue), "second crop: bottom-right");
        assert!(near(&img, cell_centre((x0, y0), 9, 9), 0, light), "free, weightless cells are light");
        assert!(x1 > x0 + side, "crops side by side");
    }

    #[test]
    fn an_episode_without_poses_is_an_error() {
        let mut record = record();
        record.log.truth.clear();
        let err = episode_figure(&tiny_room(), &record, "t").expect_err("nothing to draw");
        assert!(err.to_string().contains("episode 3"), "{err}");
    }
}
