//! The figures' typeface, compiled in: DejaVu Sans (Bitstream Vera licence, DejaVu changes in the
//! public domain; the text is in `font/LICENSE`), registered with plotters as "sans-serif" so every
//! machine draws the same text and no system font is ever looked up.
//!
//! `font/DejaVuSans-subset.ttf` (31 KB; the full face is 740 KB) keeps Latin-1, Greek, general
//! punctuation, super/subscripts, arrows and a few math signs, without hinting:
//! `pyftsubset DejaVuSans.ttf --unicodes="U+0020-007E,U+00A0-00FF,U+0391-03C9,U+2010-2027,U+2030-2033,U+2070-209F,U+2190-2193,U+2212,U+2248,U+2260,U+2264-2265" --no-hinting --layout-features=kern`
//! on `ttf/DejaVuSans.ttf` of the dejavu-fonts-ttf-2.37 release. Characters outside it draw as
//! the font's empty box.

use plotters::style::{FontStyle, register_font};
use std::sync::Once;

static DEJAVU_SANS: &[u8] = include_bytes!("font/DejaVuSans-subset.ttf");

/// Registers the embedded font as plotters' "sans-serif" family; call before drawing any text
/// (later calls do nothing). Plotters finds no font of its own: it is built without system fonts.
pub fn register_sans_serif() {
    static REGISTERED: Once = Once::new();
    REGISTERED.call_once(|| {
        let parsed = register_font("sans-serif", FontStyle::Normal, DEJAVU_SANS).is_ok();
        assert!(parsed, "the embedded DejaVu Sans subset parses as a TrueType font");
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use plotters::prelude::*;

    #[test]
    fn register_sans_serif_draws_text_inside_its_measured_box() {
        register_sans_serif();
        let (w, h) = (120u32, 40u32);
        let mut buf = vec![255u8; (w * h * 3) as usize];
        let style = ("sans-serif", 24).into_font().color(&BLACK);
        let (tw, th) = {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            let size = root.estimate_text_size("1 m θ", &style).expect("the font is registered");
            root.draw(&Text::new("1 m θ", (4, 8), style)).expect("text draws");
            root.present().expect("present");
            size
        };
        let dark = |x: u32, y: u32| buf[((y * w + x) * 3) as usize] < 128;
        let inked: Vec<(u32, u32)> =
            (0..w).flat_map(|x| (0..h).map(move |y| (x, y))).filter(|&(x, y)| dark(x, y)).collect();
        assert!(inked.len() > 40, "glyphs leave ink: {} dark pixels", inked.len());
        assert!((30..90).contains(&tw) && (10..30).contains(&th), "measured box {tw} × {th}");
        let right = inked.iter().map(|p| p.0).max().expect("ink");
        assert!(right <= 4 + tw + 2, "ink ends at x = {right}, inside the measured width {tw}");
    }
}
