//! The learning curves of a training run as a PNG: two series per logged step (PF-net: training
//! and validation loss; SAC: the episodes' pose loss, at the end and summed).

use crate::eval::{FigureError, encode_png, register_sans_serif};
use image::{Rgb, RgbImage};
use plotters::prelude::*;

const SIZE: (u32, u32) = (900, 520);
const TEXT: (&str, u32) = ("sans-serif", 27);
const TRAIN: RGBColor = RGBColor(40, 70, 220);
const VALIDATION: RGBColor = RGBColor(235, 95, 0);

fn draw_err(e: impl std::error::Error) -> FigureError {
    FigureError::Draw(e.to_string())
}

/// Axis descriptions and the two series' names.
pub struct CurveLabels<'a> {
    pub x: &'a str,
    pub y: &'a str,
    pub series: [&'a str; 2],
}

/// PNG bytes of the curves; `points` are (step, training loss, validation loss).
pub fn loss_curves_png(points: &[(u64, f64, f64)], title: &str) -> Result<Vec<u8>, FigureError> {
    let labels = CurveLabels { x: "gradient step", y: "loss", series: ["training", "validation"] };
    curves_png(points, title, &labels)
}

/// PNG bytes of two curves; `points` are (x, first series, second series).
pub fn curves_png(
    points: &[(u64, f64, f64)],
    title: &str,
    labels: &CurveLabels,
) -> Result<Vec<u8>, FigureError> {
    let mut canvas = RgbImage::from_pixel(SIZE.0, SIZE.1, Rgb([255, 255, 255]));
    {
        register_sans_serif();
        let root = BitMapBackend::with_buffer(&mut canvas, SIZE).into_drawing_area();
        let finite = points.iter().flat_map(|p| [p.1, p.2]).filter(|v| v.is_finite());
        let high = finite.fold(0.0f64, f64::max).max(1e-3) * 1.1;
        let last = points.last().map_or(1, |p| p.0).max(1) as f64;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, TEXT)
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(110)
            .build_cartesian_2d(0f64..last, 0f64..high)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(labels.x)
            .y_desc(labels.y)
            .x_labels(6)
            .y_labels(6)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.3}"))
            .label_style(TEXT)
            .axis_desc_style(TEXT)
            .light_line_style(RGBColor(236, 236, 236))
            .draw()
            .map_err(draw_err)?;
        for (name, colour, pick) in [(labels.series[0], TRAIN, 1), (labels.series[1], VALIDATION, 2)] {
            let series = points.iter().map(|p| (p.0 as f64, if pick == 1 { p.1 } else { p.2 }));
            let style = colour.stroke_width(3);
            chart
                .draw_series(LineSeries::new(series, style))
                .map_err(draw_err)?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        }
        chart
            .configure_series_labels()
            .label_font(TEXT)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    encode_png(&canvas)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loss_curves_png_draws_a_decodable_image() {
        let points = [(10, 1.0, 1.2), (20, 0.5, 0.7), (30, 0.2, 0.4)];
        let png = loss_curves_png(&points, "pfnet compact").unwrap();
        let image = image::load_from_memory(&png).expect("a PNG");
        assert_eq!((image.width(), image.height()), SIZE);
        let rgb = image.to_rgb8();
        let has = |c: RGBColor| rgb.pixels().any(|p| p.0 == [c.0, c.1, c.2]);
        assert!(has(TRAIN) && has(VALIDATION), "both curves must be drawn");
    }
}
