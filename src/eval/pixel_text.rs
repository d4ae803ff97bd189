//! Text for plotters without a font engine: plotters built without `ttf`/`ab_glyph` panics when
//! it draws text, so `PixelText` wraps a backend and draws every label with a 5×7 pixel font,
//! scaled by whole pixels. Plotters lays out some boxes (series legends) with its own estimate,
//! 0.455 × size per character, so the scale is chosen for text never to be wider than that.

use plotters::prelude::*;
use plotters_backend::text_anchor::{HPos, VPos};
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind, FontTransform,
};

/// Glyph rows top to bottom, bit 4 = leftmost column; `drop` moves a glyph down by that many
/// rows (descenders). Characters missing here draw as '?'.
struct Glyph {
    ch: char,
    rows: [u8; 7],
    drop: i32,
}

const fn g(ch: char, rows: [u8; 7]) -> Glyph {
    Glyph { ch, rows, drop: 0 }
}

const fn d(ch: char, rows: [u8; 7]) -> Glyph {
    Glyph { ch, rows, drop: 2 }
}

#[rustfmt::skip]
const GLYPHS: &[Glyph] = &[
    g(' ', [0, 0, 0, 0, 0, 0, 0]),
    g('0', [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E]), g('1', [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E]),
    g('2', [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F]), g('3', [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E]),
    g('4', [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02]), g('5', [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E]),
    g('6', [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E]), g('7', [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08]),
    g('8', [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E]), g('9', [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C]),
    g('A', [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11]), g('B', [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E]),
    g('C', [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E]), g('D', [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C]),
    g('E', [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F]), g('F', [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10]),
    g('G', [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F]), g('H', [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11]),
    g('I', [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E]), g('J', [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C]),
    g('K', [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11]), g('L', [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F]),
    g('M', [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11]), g('N', [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11]),
    g('O', [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E]), g('P', [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10]),
    g('Q', [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D]), g('R', [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11]),
    g('S', [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E]), g('T', [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04]),
    g('U', [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E]), g('V', [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04]),
    g('W', [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A]), g('X', [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11]),
    g('Y', [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04]), g('Z', [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F]),
    g('a', [0, 0, 0x0E, 0x01, 0x0F, 0x11, 0x0F]), g('b', [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E]),
    g('c', [0, 0, 0x0E, 0x10, 0x10, 0x11, 0x0E]), g('d', [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F]),
    g('e', [0, 0, 0x0E, 0x11, 0x1F, 0x10, 0x0E]), g('f', [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08]),
    d('g', [0x0F, 0x11, 0x11, 0x13, 0x0D, 0x01, 0x0E]), g('h', [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11]),
    g('i', [0x04, 0, 0x0C, 0x04, 0x04, 0x04, 0x0E]), g('j', [0x02, 0, 0x06, 0x02, 0x02, 0x12, 0x0C]),
    g('k', [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12]), g('l', [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E]),
    g('m', [0, 0, 0x1A, 0x15, 0x15, 0x11, 0x11]), g('n', [0, 0, 0x16, 0x19, 0x11, 0x11, 0x11]),
    g('o', [0, 0, 0x0E, 0x11, 0x11, 0x11, 0x0E]), d('p', [0x1E, 0x11, 0x11, 0x11, 0x1E, 0x10, 0x10]),
    d('q', [0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x01]), g('r', [0, 0, 0x16, 0x19, 0x10, 0x10, 0x10]),
    g('s', [0, 0, 0x0F, 0x10, 0x0E, 0x01, 0x1E]), g('t', [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06]),
    g('u', [0, 0, 0x11, 0x11, 0x11, 0x13, 0x0D]), g('v', [0, 0, 0x11, 0x11, 0x11, 0x0A, 0x04]),
    g('w', [0, 0, 0x11, 0x11, 0x15, 0x15, 0x0A]), g('x', [0, 0, 0x11, 0x0A, 0x04, 0x0A, 0x11]),
    d('y', [0x11, 0x11, 0x11, 0x13, 0x0D, 0x01, 0x0E]), g('z', [0, 0, 0x1F, 0x02, 0x04, 0x08, 0x1F]),
    g('!', [0x04, 0x04, 0x04, 0x04, 0x04, 0, 0x04]), g('%', [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03]),
    g('(', [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02]), g(')', [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08]),
    g('+', [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0]), d(',', [0, 0, 0, 0, 0x06, 0x04, 0x08]),
    g('-', [0, 0, 0, 0x1F, 0, 0, 0]), g('–', [0, 0, 0, 0x1F, 0, 0, 0]),
    g('.', [0, 0, 0, 0, 0, 0x0C, 0x0C]), g('/', [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0]),
    g(':', [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0]), g('=', [0, 0, 0x1F, 0, 0x1F, 0, 0]),
    g('[', [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E]), g(']', [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E]),
    d('_', [0, 0, 0, 0, 0, 0, 0x1F]), g('|', [0x04; 7]), g('·', [0, 0, 0, 0x0C, 0x0C, 0, 0]),
    g('<', [0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02]), g('>', [0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08]),
    g('?', [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04]), g('\'', [0x04, 0x04, 0x08, 0, 0, 0, 0]),
    g('°', [0x0C, 0x12, 0x12, 0x0C, 0, 0, 0]), g('×', [0, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0]),
    g('#', [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A]), g('*', [0, 0x04, 0x15, 0x0E, 0x15, 0x04, 0]),
    g('θ', [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x0E]),
];

fn glyph(ch: char) -> &'static Glyph {
    let find = |c: char| GLYPHS.iter().find(|g| g.ch == c);
    find(ch).or_else(|| find('?')).expect("'?' is in the glyph table")
}

/// Glyph pixel size in screen pixels for a plotters font size: 6 columns × scale ≤ 0.455 × size
/// (size 27 → 2, size 40 → 3).
pub fn scale(font_size: f64) -> i32 {
    ((font_size * 0.455 / 6.0).floor() as i32).max(1)
}

/// Width and height of a line of text in screen pixels: 6 columns per character (one blank),
/// 9 rows (7 plus 2 for descenders).
pub fn text_size(text: &str, font_size: f64) -> (u32, u32) {
    let s = scale(font_size);
    let n = text.chars().count() as i32;
    (((6 * n - 1).max(0) * s) as u32, (9 * s) as u32)
}

/// A backend that draws text with the pixel font and passes everything else through.
pub struct PixelText<B>(pub B);

type Drawn<B> = Result<(), DrawingErrorKind<<B as DrawingBackend>::ErrorType>>;

impl<B: DrawingBackend> DrawingBackend for PixelText<B> {
    type ErrorType = B::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.0.get_size()
    }
    fn ensure_prepared(&mut self) -> Drawn<B> {
        self.0.ensure_prepared()
    }
    fn present(&mut self) -> Drawn<B> {
        self.0.present()
    }
    fn draw_pixel(&mut self, point: BackendCoord, color: BackendColor) -> Drawn<B> {
        self.0.draw_pixel(point, color)
    }
    fn draw_line<S: BackendStyle>(&mut self, from: BackendCoord, to: BackendCoord, style: &S) -> Drawn<B> {
        self.0.draw_line(from, to, style)
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        a: BackendCoord,
        b: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Drawn<B> {
        self.0.draw_rect(a, b, style, fill)
    }
    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Drawn<B> {
        self.0.draw_path(path, style)
    }
    fn draw_circle<S: BackendStyle>(&mut self, c: BackendCoord, r: u32, style: &S, fill: bool) -> Drawn<B> {
        self.0.draw_circle(c, r, style, fill)
    }
    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Drawn<B> {
        self.0.fill_polygon(vert, style)
    }
    fn blit_bitmap(&mut self, pos: BackendCoord, size: (u32, u32), src: &[u8]) -> Drawn<B> {
        self.0.blit_bitmap(pos, size, src)
    }

    fn estimate_text_size<T: BackendTextStyle>(
        &self,
        text: &str,
        style: &T,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        Ok(text_size(text, style.size()))
    }

    fn draw_text<T: BackendTextStyle>(&mut self, text: &str, style: &T, pos: BackendCoord) -> Drawn<B> {
        let color = style.color();
        if color.alpha == 0.0 {
            return Ok(());
        }
        let s = scale(style.size());
        let (w, h) = text_size(text, style.size());
        let anchor = style.anchor();
        let dx = match anchor.h_pos {
            HPos::Left => 0,
            HPos::Center => -(w as i32) / 2,
            HPos::Right => -(w as i32),
        };
        let dy = match anchor.v_pos {
            VPos::Top => 0,
            VPos::Center => -(h as i32) / 2,
            VPos::Bottom => -(h as i32),
        };
        let transform: FontTransform = style.transform();
        for (n, ch) in text.chars().enumerate() {
            let glyph = glyph(ch);
            for (row, bits) in glyph.rows.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) == 0 {
                        continue;
                    }
                    let x0 = dx + (6 * n as i32 + col) * s;
                    let y0 = dy + (row as i32 + glyph.drop) * s;
                    for (px, py) in (0..s).flat_map(|i| (0..s).map(move |j| (x0 + i, y0 + j))) {
                        let (tx, ty) = transform.transform(px, py);
                        self.0.draw_pixel((pos.0 + tx, pos.1 + ty), color)?;
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_glyph_fits_five_columns_and_is_listed_once() {
        for (k, g) in GLYPHS.iter().enumerate() {
            assert!(g.rows.iter().all(|r| *r < 0x20), "glyph {:?} is wider than 5 columns", g.ch);
            assert!(GLYPHS[..k].iter().all(|o| o.ch != g.ch), "glyph {:?} is listed twice", g.ch);
        }
        assert_eq!(glyph('€').ch, '?', "unknown characters fall back to '?'");
    }

    #[test]
    fn pixel_text_draws_text_where_anchored() {
        let (w, h) = (80u32, 30u32);
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let root = PixelText(BitMapBackend::with_buffer(&mut buf, (w, h))).into_drawing_area();
            root.draw(&Text::new("1 m", (2, 2), ("sans-serif", 27).into_font().color(&BLACK)))
                .expect("text draws without a font engine");
            root.present().expect("present");
        }
        let dark = |x: u32, y: u32| buf[((y * w + x) * 3) as usize] < 128;
        let (tw, th) = text_size("1 m", 27.0);
        assert_eq!((tw, th), (34, 18), "3 glyphs at scale 2");
        assert!((2..2 + tw).any(|x| (2..2 + th).any(|y| dark(x, y))), "text pixels inside its box");
        assert!((0..w).all(|x| (2 + th..h).all(|y| !dark(x, y))), "nothing drawn below the box");
        assert!((2 + tw..w).all(|x| (0..h).all(|y| !dark(x, y))), "nothing drawn right of the box");
    }
}
