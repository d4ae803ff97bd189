//! The README's realism figure: a real SLAM map (cropped to its known part) beside procedural
//! apartments of the paper's size with the realism layer on, all at one pixel per 0.05 m cell,
//! drawn as `apfn map render` draws (free white, occupied black, unknown grey).
//!
//! `cargo run --release --example realism_figure -- ../shared/maps/aws_small_house.yaml docs/realism.png 0 1000000`
//!
//! Arguments: the real map's YAML, the PNG to write, then the apartment seeds (default 0 and
//! 1000000, one seen and one unseen).

use anyhow::{Context, bail};
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::map::{Cell, OccupancyMap, load_ros_map, render, write_atomically};
use image::{ImageFormat, Rgb, RgbImage, imageops};
use std::io::Cursor;
use std::path::PathBuf;

/// Grey cells kept around the known part of the real map, and between panels, pixels.
const BORDER: u32 = 8;
/// Colour of the space between panels (light, so the maps' unknown grey stands out).
const BACKGROUND: Rgb<u8> = Rgb([235, 235, 235]);

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [real, out, seeds @ ..] = args.as_slice() else {
        bail!("usage: realism_figure REAL_MAP.yaml OUT.png [SEED ...]");
    };
    let seeds: Vec<u64> = if seeds.is_empty() {
        vec![0, 1_000_000]
    } else {
        seeds.iter().map(|s| s.parse().with_context(|| format!("seed {s:?}"))).collect::<Result<_, _>>()?
    };
    let real = load_ros_map(&PathBuf::from(real))?;
    let mut panels = vec![known_part(&real)];
    for seed in seeds {
        panels.push(render(&generate_apartment(seed, &ApartmentParams::paper_size()), None));
    }
    let width = panels.iter().map(|p| p.width() + BORDER).sum::<u32>() + BORDER;
    let height = panels.iter().map(RgbImage::height).max().unwrap_or(0) + 2 * BORDER;
    let mut figure = RgbImage::from_pixel(width, height, BACKGROUND);
    let mut x = BORDER;
    for panel in &panels {
        let y = (height - panel.height()) / 2;
        imageops::replace(&mut figure, panel, i64::from(x), i64::from(y));
        x += panel.width() + BORDER;
    }
    let mut png = Vec::new();
    figure.write_to(&mut Cursor::new(&mut png), ImageFormat::Png).context("encoding the PNG")?;
    write_atomically(&PathBuf::from(out), &png)?;
    println!("wrote {out}: {width} × {height} px, {} KB", png.len() / 1024);
    Ok(())
}

/// The map drawn and cropped to its cells that are not unknown, plus a border.
fn known_part(map: &OccupancyMap) -> RgbImage {
    let (mut i0, mut j0, mut i1, mut j1) = (map.width, map.height, 0, 0);
    for j in 0..map.height {
        for i in 0..map.width {
            if map.get(i, j) != Cell::Unknown {
                (i0, j0, i1, j1) = (i0.min(i), j0.min(j), i1.max(i + 1), j1.max(j + 1));
            }
        }
    }
    let image = render(map, None);
    let b = BORDER as usize;
    let (x0, x1) = (i0.saturating_sub(b), (i1 + b).min(map.width));
    // Image rows run top down: map row j is image row height − 1 − j.
    let (y0, y1) = (map.height - (j1 + b).min(map.height), map.height - j0.saturating_sub(b));
    imageops::crop_imm(&image, x0 as u32, y0 as u32, (x1 - x0) as u32, (y1 - y0) as u32).to_image()
}
