//! ROS map_server / nav2 map files: a YAML beside a PGM or PNG image.
//!
//! Loading follows nav2's `map_io` semantics: the image path is relative to the YAML's folder
//! (or absolute); colour channels are averaged; `p = (255 − v)/255` (or `v/255` with `negate`);
//! `p > occupied_thresh` → occupied, `p < free_thresh` → free, else unknown. `scale` mode keeps
//! the same two thresholds; its in-between grey levels become unknown (we only need "blocks" vs
//! "free"). `raw` mode reads the pixel value as OccupancyGrid data: 0..=100 is divided by 100 and
//! thresholded like trinary, anything else (255, i.e. −1) is unknown; as in nav2 (unlike ROS 1),
//! `negate` does not apply to raw values. A fully transparent pixel (alpha 0) is unknown in
//! trinary and scale mode. Image row 0 is the top of the map; `origin` is the pose of the
//! bottom-left pixel, yaw included.

use crate::limits::{MAP_ORIGIN_M, MAP_PIXELS, MAP_RESOLUTION_M, MAP_SIDE_M, MAP_SIDE_PX, thousands};
use crate::world::map::error::MapError;
use crate::world::map::occupancy::{Cell, OccupancyMap};
use crate::world::pose::Pose2;
use image::DynamicImage;
use serde_norway::{Mapping, Value};
use std::io::Write;
use std::path::{Path, PathBuf};

/// How grey levels turn into occupancy (the YAML's `mode`; absent means trinary).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapMode {
    Trinary,
    Scale,
    Raw,
}

/// The fields of a map YAML, validated; `image` is resolved against the YAML's folder.
#[derive(Clone, Debug, PartialEq)]
pub struct RosMapYaml {
    pub image: PathBuf,
    pub resolution_m: f32,
    pub origin: Pose2,
    pub negate: bool,
    pub occupied_thresh: f64,
    pub free_thresh: f64,
    pub mode: MapMode,
}

/// Unknown level written by map_saver (p = 50/255 ≈ 0.196).
pub(super) const PGM_UNKNOWN: u8 = 205;
/// Free level written by map_saver.
pub(super) const PGM_FREE: u8 = 254;
/// Occupied level written by map_saver.
pub(super) const PGM_OCCUPIED: u8 = 0;
/// Thresholds written by `save_ros_map`. The free threshold is ROS 1 map_saver's 0.196, not
/// nav2's 0.25: with 0.25 the unknown level 205 (p ≈ 0.19608) would read back as free.
pub(super) const SAVE_OCCUPIED_THRESH: f64 = 0.65;
pub(super) const SAVE_FREE_THRESH: f64 = 0.196;

/// Loads a ROS map (YAML + PGM/PNG). Fails with a [`MapError`] naming the file and field when the
/// YAML or image is missing or invalid, or when the map has no free cell.
pub fn load_ros_map(yaml_path: &Path) -> Result<OccupancyMap, MapError> {
    let meta = read_ros_yaml(yaml_path)?;
    if !meta.image.exists() {
        return Err(MapError::ImageMissing { yaml: yaml_path.to_path_buf(), image: meta.image });
    }
    let unreadable = |e: &dyn std::fmt::Display| MapError::ImageUnreadable {
        path: meta.image.clone(),
        reason: e.to_string(),
    };
    let open = || image::ImageReader::open(&meta.image).and_then(|r| r.with_guessed_format());
    let (width, height) =
        open().map_err(|e| unreadable(&e))?.into_dimensions().map_err(|e| unreadable(&e))?;
    check_image_size(&meta, width, height)?;
    let mut reader = open().map_err(|e| unreadable(&e))?;
    reader.limits(decoder_limits());
    let img = reader.decode().map_err(|e| unreadable(&e))?;
    let map = occupancy_from_image(&img, &meta);
    if map.counts().0 == 0 {
        return Err(MapError::NoFreeSpace { path: yaml_path.to_path_buf() });
    }
    Ok(map)
}

/// Fails unless a `width × height` image at the YAML's resolution fits the map limits of
/// [`crate::limits`]; only the image header has been read so far.
fn check_image_size(meta: &RosMapYaml, width: u32, height: u32) -> Result<(), MapError> {
    let (w, h) = (u64::from(width), u64::from(height));
    let side_m = |px: u64| px as f64 * f64::from(meta.resolution_m);
    let fits =
        w > 0 && h > 0 && w.max(h) <= MAP_SIDE_PX && w * h <= MAP_PIXELS && side_m(w.max(h)) <= MAP_SIDE_M;
    if fits {
        return Ok(());
    }
    Err(MapError::ImageTooLarge {
        path: meta.image.clone(),
        width,
        height,
        resolution_m: meta.resolution_m,
        width_m: side_m(w) as f32,
        height_m: side_m(h) as f32,
        expected: format!(
            "1 to {} pixels per side, at most {} pixels, and at most {} m per side",
            thousands(MAP_SIDE_PX),
            thousands(MAP_PIXELS),
            thousands(MAP_SIDE_M as u64)
        ),
    })
}

/// The decoder's own ceiling, for what a header cannot tell (e.g. PNG text chunks): the largest
/// allowed map as 4-channel pixels.
fn decoder_limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAP_SIDE_PX as u32);
    limits.max_image_height = Some(MAP_SIDE_PX as u32);
    limits.max_alloc = Some(MAP_PIXELS * 4 * 2);
    limits
}

/// Reads and validates a map YAML without touching the image.
pub fn read_ros_yaml(yaml_path: &Path) -> Result<RosMapYaml, MapError> {
    let path = yaml_path.to_path_buf();
    let text = std::fs::read_to_string(yaml_path)
        .map_err(|source| MapError::YamlUnreadable { path: path.clone(), source })?;
    if let Some((line, column)) = too_deep(&text) {
        let message = format!(
            "brackets nested deeper than {MAX_YAML_NESTING} levels; expected flat `key: value` lines (the deepest is `origin: [x, y, yaw]`)"
        );
        return Err(MapError::YamlParse { path, line, column, message });
    }
    let value: Value = serde_norway::from_str(&text).map_err(|e| {
        let (line, column) = e.location().map_or((0, 0), |l| (l.line(), l.column()));
        MapError::YamlParse { path: path.clone(), line, column, message: e.to_string() }
    })?;
    let Some(doc) = value.as_mapping() else {
        return Err(MapError::YamlParse {
            path,
            line: 1,
            column: 1,
            message: "expected a mapping of `key: value` lines".into(),
        });
    };
    let fields = Fields { path: &path, doc };

    let image_name = fields.require("image", "a relative or absolute image path")?;
    let image_name =
        image_name.as_str().ok_or_else(|| fields.invalid("image", "a path string", image_name))?;
    let image = yaml_path.parent().unwrap_or(Path::new("")).join(image_name);

    let (min_res, max_res) = MAP_RESOLUTION_M;
    let resolution_m =
        fields.number("resolution", &format!("metres per pixel in [{min_res}, {max_res}]"), |r| {
            (min_res..=max_res).contains(&r)
        })?;
    let origin = fields.origin()?;
    let negate = fields.negate()?;
    let in_unit = |t: f64| (0.0..=1.0).contains(&t);
    let occupied_thresh = fields.number("occupied_thresh", "a number in [0, 1]", in_unit)?;
    let free_thresh = fields.number("free_thresh", "a number in [0, 1]", in_unit)?;
    let mode = match doc.get("mode") {
        None => MapMode::Trinary,
        Some(v) => match v.as_str() {
            Some("trinary") => MapMode::Trinary,
            Some("scale") => MapMode::Scale,
            Some("raw") => MapMode::Raw,
            _ => return Err(fields.invalid("mode", "one of trinary, scale, raw", v)),
        },
    };
    Ok(RosMapYaml {
        image,
        resolution_m: resolution_m as f32,
        origin,
        negate,
        occupied_thresh,
        free_thresh,
        mode,
    })
}

/// Deepest `[`/`{` nesting read as a map YAML: the YAML scanner takes seconds on tens of
/// thousands of nested brackets before its own recursion limit applies.
const MAX_YAML_NESTING: usize = 16;

/// The 1-based line and column where brackets nest deeper than [`MAX_YAML_NESTING`], if they do.
fn too_deep(text: &str) -> Option<(usize, usize)> {
    let mut depth = 0usize;
    for (row, line) in text.lines().enumerate() {
        for (col, c) in line.chars().enumerate() {
            match c {
                '[' | '{' => depth += 1,
                ']' | '}' => depth = depth.saturating_sub(1),
                _ => {}
            }
            if depth > MAX_YAML_NESTING {
                return Some((row + 1, col + 1));
            }
        }
    }
    None
}

/// Field access with errors that name the file and the field.
struct Fields<'a> {
    path: &'a Path,
    doc: &'a Mapping,
}

impl Fields<'_> {
    fn require(&self, field: &'static str, expected: &str) -> Result<&Value, MapError> {
        self.doc.get(field).ok_or_else(|| MapError::MissingField {
            path: self.path.into(),
            field,
            expected: expected.into(),
        })
    }

    fn invalid(&self, field: &'static str, expected: &str, found: &Value) -> MapError {
        let found = serde_norway::to_string(found).map_or_else(|_| format!("{found:?}"), |s| s.trim().into());
        MapError::InvalidField { path: self.path.into(), field, expected: expected.into(), found }
    }

    fn number(
        &self,
        field: &'static str,
        expected: &str,
        valid: impl Fn(f64) -> bool,
    ) -> Result<f64, MapError> {
        let v = self.require(field, expected)?;
        v.as_f64().filter(|x| x.is_finite() && valid(*x)).ok_or_else(|| self.invalid(field, expected, v))
    }

    fn origin(&self) -> Result<Pose2, MapError> {
        let expected = format!(
            "a list [x, y, yaw] of three finite numbers (metres, metres, radians), |x| and |y| ≤ {} m",
            thousands(MAP_ORIGIN_M as u64)
        );
        let v = self.require("origin", &expected)?;
        let xs: Option<Vec<f64>> =
            v.as_sequence().and_then(|s| s.iter().map(|e| e.as_f64().filter(|x| x.is_finite())).collect());
        match xs.as_deref() {
            Some(&[x, y, yaw]) if x.abs().max(y.abs()) <= MAP_ORIGIN_M => {
                Ok(Pose2::new(x as f32, y as f32, yaw as f32))
            }
            _ => Err(self.invalid("origin", &expected, v)),
        }
    }

    fn negate(&self) -> Result<bool, MapError> {
        const EXPECTED: &str = "0 or 1 (or true/false)";
        let v = self.require("negate", EXPECTED)?;
        match (v.as_bool(), v.as_i64()) {
            (Some(b), _) => Ok(b),
            (_, Some(0)) => Ok(false),
            (_, Some(1)) => Ok(true),
            _ => Err(self.invalid("negate", EXPECTED, v)),
        }
    }
}

/// Turns a decoded image into cells with the YAML's semantics (row 0 of the image = top row).
pub fn occupancy_from_image(img: &DynamicImage, meta: &RosMapYaml) -> OccupancyMap {
    let converted;
    let (raw, channels, has_alpha): (&[u8], usize, bool) = match img {
        DynamicImage::ImageLuma8(b) => (b.as_raw(), 1, false),
        DynamicImage::ImageLumaA8(b) => (b.as_raw(), 2, true),
        DynamicImage::ImageRgb8(b) => (b.as_raw(), 3, false),
        DynamicImage::ImageRgba8(b) => (b.as_raw(), 4, true),
        other => {
            converted = other.to_rgba8();
            (converted.as_raw(), 4, true)
        }
    };
    let (width, height) = (img.width() as usize, img.height() as usize);
    let colour_channels = if has_alpha { channels - 1 } else { channels };
    let mut map = OccupancyMap::filled(width, height, meta.resolution_m, Cell::Unknown);
    map.origin = meta.origin;
    for (k, px) in raw.chunks_exact(channels).enumerate() {
        let (col, row) = (k % width, k / width);
        let mean = px[..colour_channels].iter().map(|&c| f64::from(c)).sum::<f64>() / colour_channels as f64;
        let alpha = if has_alpha { px[channels - 1] } else { u8::MAX };
        map.set(col, height - 1 - row, classify_pixel(meta, mean, alpha));
    }
    map
}

/// One pixel's cell: `mean` is the average of its colour channels (0..=255).
pub fn classify_pixel(meta: &RosMapYaml, mean: f64, alpha: u8) -> Cell {
    let threshold = |p: f64| {
        if p > meta.occupied_thresh {
            Cell::Occupied
        } else if p < meta.free_thresh {
            Cell::Free
        } else {
            Cell::Unknown
        }
    };
    match meta.mode {
        MapMode::Raw => {
            let v = mean.round();
            if (0.0..=100.0).contains(&v) { threshold(v / 100.0) } else { Cell::Unknown }
        }
        MapMode::Trinary | MapMode::Scale if alpha == 0 => Cell::Unknown,
        MapMode::Trinary | MapMode::Scale => {
            threshold(if meta.negate { mean / 255.0 } else { (255.0 - mean) / 255.0 })
        }
    }
}

/// Writes `map` as `<stem>.pgm` (P5, trinary: 254 free, 0 occupied, 205 unknown) beside
/// `yaml_path`, then the YAML. Each file is written to a temporary sibling and renamed into
/// place, so a failure never leaves a truncated file behind.
pub fn save_ros_map(map: &OccupancyMap, yaml_path: &Path) -> Result<(), MapError> {
    let stem = yaml_path.file_stem().and_then(|s| s.to_str()).ok_or_else(|| MapError::Write {
        path: yaml_path.into(),
        source: std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "the YAML path needs a UTF-8 file name",
        ),
    })?;
    let image_name = format!("{stem}.pgm");
    let mut pgm = format!("P5\n{} {}\n255\n", map.width, map.height).into_bytes();
    pgm.reserve(map.cells.len());
    for j in (0..map.height).rev() {
        pgm.extend(map.cells[j * map.width..(j + 1) * map.width].iter().map(|c| match c {
            Cell::Free => PGM_FREE,
            Cell::Occupied => PGM_OCCUPIED,
            Cell::Unknown => PGM_UNKNOWN,
        }));
    }
    let o = map.origin;
    let yaml = format!(
        "image: {image_name}\nmode: trinary\nresolution: {}\norigin: [{}, {}, {}]\nnegate: 0\n\
         occupied_thresh: {SAVE_OCCUPIED_THRESH}\nfree_thresh: {SAVE_FREE_THRESH}\n",
        map.resolution_m, o.x, o.y, o.yaw
    );
    write_atomically(&yaml_path.with_file_name(image_name), &pgm)?;
    write_atomically(yaml_path, yaml.as_bytes())
}

/// Writes `bytes` to a temporary file beside `path`, syncs it and renames it over `path`.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), MapError> {
    let name = path.file_name().map_or_else(|| "map".into(), |n| n.to_string_lossy().into_owned());
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    let attempt = || -> std::io::Result<()> {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    };
    attempt().map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        MapError::Write { path: path.into(), source }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, Luma, Rgba, RgbaImage};

    fn meta(mode: MapMode, negate: bool) -> RosMapYaml {
        RosMapYaml {
            image: PathBuf::new(),
            resolution_m: 0.05,
            origin: Pose2::default(),
            negate,
            occupied_thresh: 0.65,
            free_thresh: 0.196,
            mode,
        }
    }

    #[test]
    fn trinary_thresholds_and_negate() {
        let m = meta(MapMode::Trinary, false);
        assert_eq!(classify_pixel(&m, 254.0, 255), Cell::Free, "white is free");
        assert_eq!(classify_pixel(&m, 0.0, 255), Cell::Occupied, "black is occupied");
        assert_eq!(classify_pixel(&m, 205.0, 255), Cell::Unknown, "205 → p = 0.19608 > 0.196");
        assert_eq!(classify_pixel(&m, 254.0, 0), Cell::Unknown, "transparent is unknown");
        let n = meta(MapMode::Trinary, true);
        assert_eq!(classify_pixel(&n, 254.0, 255), Cell::Occupied, "negate: white is occupied");
        assert_eq!(classify_pixel(&n, 0.0, 255), Cell::Free, "negate: black is free");
    }

    #[test]
    fn scale_in_between_is_unknown_and_raw_reads_percentages() {
        let s = meta(MapMode::Scale, false);
        assert_eq!(classify_pixel(&s, 128.0, 255), Cell::Unknown, "p ≈ 0.5 lies between thresholds");
        let r = meta(MapMode::Raw, true);
        assert_eq!(classify_pixel(&r, 0.0, 255), Cell::Free, "raw 0 is free (negate ignored)");
        assert_eq!(classify_pixel(&r, 100.0, 255), Cell::Occupied, "raw 100 is occupied");
        assert_eq!(classify_pixel(&r, 50.0, 255), Cell::Unknown, "raw 50 is between thresholds");
        assert_eq!(classify_pixel(&r, 255.0, 255), Cell::Unknown, "raw 255 (−1) is unknown");
        assert_eq!(classify_pixel(&r, 150.0, 255), Cell::Unknown, "raw > 100 is unknown");
    }

    #[test]
    fn image_row_zero_is_the_top_and_rgba_channels_are_averaged() {
        let mut img = RgbaImage::from_pixel(3, 2, Rgba([255, 255, 255, 255]));
        img.put_pixel(0, 0, Rgba([0, 0, 30, 255])); // top-left, mean 10 → occupied
        img.put_pixel(2, 1, Rgba([255, 255, 255, 0])); // bottom-right, transparent → unknown
        let map = occupancy_from_image(&DynamicImage::ImageRgba8(img), &meta(MapMode::Trinary, false));
        assert_eq!(map.get(0, 1), Cell::Occupied, "image top-left is cell (0, height−1)");
        assert_eq!(map.get(2, 0), Cell::Unknown, "image bottom-right is cell (width−1, 0)");
        assert_eq!(map.counts(), (4, 1, 1));
    }

    #[test]
    fn save_then_load_round_trips_exactly() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut map = OccupancyMap::from_ascii(0.05, "#..?\n....\n.##.");
        map.origin = Pose2::new(-15.1, 2.25, 0.3);
        let yaml = dir.path().join("room.yaml");
        save_ros_map(&map, &yaml).expect("save");
        assert!(dir.path().join("room.pgm").exists(), "the image sits beside the YAML");
        let back = load_ros_map(&yaml).expect("load");
        assert_eq!(back, map, "export then import must give the identical grid");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(leftovers.is_empty(), "no temporary files left behind: {leftovers:?}");
    }

    #[test]
    fn ascii_pgm_absolute_path_and_missing_mode() {
        let dir = tempfile::tempdir().expect("temp dir");
        let pgm = dir.path().join("p2.pgm");
        std::fs::write(&pgm, "P2\n2 2\n255\n0 254\n205 254\n").expect("write pgm");
        let yaml = dir.path().join("sub").join("m.yaml");
        std::fs::create_dir(dir.path().join("sub")).expect("mkdir");
        let text = format!(
            "image: {}\nresolution: 0.1\norigin: [1, 2, 0.5]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            pgm.display()
        );
        std::fs::write(&yaml, text).expect("write yaml");
        let map = load_ros_map(&yaml).expect("absolute image path, no mode line");
        assert_eq!((map.width, map.height), (2, 2));
        assert_eq!(map.origin, Pose2::new(1.0, 2.0, 0.5), "origin yaw is honoured");
        assert_eq!(map.get(0, 1), Cell::Occupied, "P2 top-left 0 is occupied");
        assert_eq!(map.get(0, 0), Cell::Unknown, "P2 bottom-left 205 is unknown");
        assert_eq!(map.get(1, 0), Cell::Free);
    }

    /// A map YAML with `resolution` beside an image written as `image` bytes; the load error.
    fn load_error(resolution: &str, image: &[u8]) -> (String, PathBuf) {
        let dir = tempfile::tempdir().expect("temp dir");
        std::fs::write(dir.path().join("m.pgm"), image).expect("write image");
        let yaml = dir.path().join("m.yaml");
        let text = format!(
            "image: m.pgm\nresolution: {resolution}\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n"
        );
        std::fs::write(&yaml, text).expect("write yaml");
        (load_ros_map(&yaml).expect_err("out of range").to_string(), yaml)
    }

    #[test]
    fn resolutions_outside_the_sane_range_are_rejected() {
        let pgm = b"P2\n2 1\n255\n254 254\n";
        for given in ["0.00001", "100"] {
            let (e, yaml) = load_error(given, pgm);
            let want = format!(
                "map YAML {}: field `resolution` is {given}; expected metres per pixel in [0.005, 0.5]",
                yaml.display()
            );
            assert_eq!(e, want, "resolution {given}");
        }
    }

    #[test]
    fn deeply_nested_yaml_is_refused_before_the_parser_runs() {
        // Found by `apfn fuzz --target map`: 35,000 `{` after `negate:` took 2.3 s of CPU to parse.
        let dir = tempfile::tempdir().expect("temp dir");
        let yaml = dir.path().join("deep.yaml");
        std::fs::write(&yaml, format!("image: m.pgm\nnegate: {}\n", "{".repeat(35_000))).expect("write");
        let e = read_ros_yaml(&yaml).expect_err("nested too deep").to_string();
        let want = format!(
            "map YAML {} is not valid YAML at line 2, column 25: brackets nested deeper than 16 levels; \
             expected flat `key: value` lines (the deepest is `origin: [x, y, yaw]`)",
            yaml.display()
        );
        assert_eq!(e, want);
    }

    #[test]
    fn image_sizes_are_checked_from_the_header_before_decoding() {
        // Headers only: decoding any of them would fail (no pixels) or allocate gigabytes.
        let too_many = load_error("0.05", b"P5\n20000 20000\n255\n").0;
        assert!(
            too_many.contains("is 20000 × 20000 pixels (1000 × 1000 m at 0.05 m per pixel)"),
            "{too_many}"
        );
        assert!(too_many.ends_with("expected 1 to 10,000 pixels per side, at most 25,000,000 pixels, and at most 1,000 m per side"), "{too_many}");
        let too_wide = load_error("0.5", b"P5\n4000 10\n255\n").0;
        assert!(too_wide.contains("(2000 × 5 m at 0.5 m per pixel)"), "a map wider than 1 km: {too_wide}");
        let fits = load_error("0.05", b"P5\n2000 2000\n255\n").0;
        assert!(
            fits.contains("cannot be decoded"),
            "within limits, the decoder runs (and finds no pixels): {fits}"
        );
    }

    #[test]
    fn invalid_fields_are_named() {
        let dir = tempfile::tempdir().expect("temp dir");
        GrayImage::from_pixel(2, 2, Luma([254])).save(dir.path().join("m.png")).expect("png");
        let base = "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n";
        let cases = [
            ("resolution: 0.1", "resolution: -1", "resolution"),
            ("origin: [0, 0, 0]", "origin: [0, 0]", "origin"),
            ("origin: [0, 0, 0]", "origin: [1e9, 0, 0]", "origin"),
            ("negate: 0", "negate: 2", "negate"),
            ("free_thresh: 0.2", "free_thresh: 1.5", "free_thresh"),
            ("occupied_thresh: 0.65", "occupied_thresh: high", "occupied_thresh"),
            ("negate: 0", "negate: 0\nmode: fancy", "mode"),
            ("image: m.png", "image: [1]", "image"),
        ];
        for (from, to, field) in cases {
            let yaml = dir.path().join(format!("{field}.yaml"));
            std::fs::write(&yaml, base.replace(from, to)).expect("write");
            match load_ros_map(&yaml) {
                Err(MapError::InvalidField { field: f, path, .. }) => {
                    assert_eq!(f, field, "wrong field named");
                    assert_eq!(path, yaml, "error names the YAML");
                }
                other => panic!("{field}: expected InvalidField, got {other:?}"),
            }
        }
        let yaml = dir.path().join("nothresh.yaml");
        std::fs::write(&yaml, base.replace("free_thresh: 0.2\n", "")).expect("write");
        assert!(
            matches!(load_ros_map(&yaml), Err(MapError::MissingField { field: "free_thresh", .. })),
            "a missing threshold is named"
        );
        let yaml = dir.path().join("ok.yaml");
        std::fs::write(&yaml, base).expect("write");
        assert_eq!(load_ros_map(&yaml).expect("valid PNG map").counts(), (4, 0, 0));
    }
}
