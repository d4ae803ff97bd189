//! The JSON Lines formats of offline replay: one [`LogLine`] per recorded scan (the fields of a
//! ROS `sensor_msgs/LaserScan` plus the `nav_msgs/Odometry` pose) and one [`EstimateLine`] per
//! filter update.
//!
//! ```json
//! {"t": 0.6, "odom": [0.41, 0.02, 0.05], "ranges": [1.2, null, 5.6], "angle_min": -2.094,
//!  "angle_increment": 0.0184, "range_min": 0.05, "range_max": 5.6, "truth": [3.1, 2.0, 1.57]}
//! ```
//!
//! `odom` is the cumulative odometry pose in the odom frame, not a per-line delta; the localizer
//! takes the motion between consecutive lines. A range that is `null`, `"nan"`, `"inf"` (or
//! Python's bare `NaN` / `Infinity`, which `json.dumps` writes) is read as NaN / ±∞ and skipped by
//! the likelihood field, as AMCL does. `truth` is optional. Fields not listed here are ignored, so
//! logs exported with extra metadata (frame ids, stamps) load as they are.

use crate::replay::error::ReplayError;
use crate::sense::LidarScan;
use crate::world::Pose2;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::borrow::Cow;
use std::path::Path;

/// One recorded scan with the odometry pose at the time of the scan.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct LogLine {
    /// Time of the scan, seconds (simulated seconds for `apfn record`).
    pub t: f64,
    /// Odometry pose [x m, y m, θ rad] in the odom frame, cumulative.
    pub odom: [f32; 3],
    /// Ranges, metres, counter-clockwise from `angle_min` (0 rad = straight ahead); NaN = no reading.
    pub ranges: Vec<f32>,
    /// Angle of the first ray in the robot frame, radians.
    pub angle_min: f32,
    /// Angle between consecutive rays, radians.
    pub angle_increment: f32,
    /// Shortest valid range, metres.
    pub range_min: f32,
    /// Longest valid range, metres; readings at or beyond it are misses.
    pub range_max: f32,
    /// True pose [x m, y m, θ rad] in the map frame at the time of the scan, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth: Option<[f32; 3]>,
}

/// One filter update, as `apfn localize` writes it.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct EstimateLine {
    /// The log line's `t`, seconds.
    pub t: f64,
    /// Estimated pose [x m, y m, θ rad] in the map frame.
    pub pose: [f32; 3],
    /// Covariance of (x, y, θ), row-major 3×3 (m², m·rad, rad²).
    pub cov: [f32; 9],
    /// Wall time of this line's update, milliseconds.
    pub update_ms: f64,
}

impl LogLine {
    /// The odometry pose.
    pub fn odom_pose(&self) -> Pose2 {
        Pose2::new(self.odom[0], self.odom[1], self.odom[2])
    }

    /// The true pose, when the log has one.
    pub fn truth_pose(&self) -> Option<Pose2> {
        self.truth.map(|[x, y, yaw]| Pose2::new(x, y, yaw))
    }

    /// The scan as the filter's `LidarScan`.
    pub fn scan(&self) -> LidarScan {
        LidarScan {
            ranges_m: self.ranges.clone(),
            angle_min_rad: self.angle_min,
            angle_increment_rad: self.angle_increment,
            range_min_m: self.range_min,
            range_max_m: self.range_max,
        }
    }

    /// A log line from a pose, a scan and the time.
    pub fn new(t: f64, odom: Pose2, scan: &LidarScan, truth: Option<Pose2>) -> Self {
        Self {
            t,
            odom: [odom.x, odom.y, odom.yaw],
            ranges: scan.ranges_m.clone(),
            angle_min: scan.angle_min_rad,
            angle_increment: scan.angle_increment_rad,
            range_min: scan.range_min_m,
            range_max: scan.range_max_m,
            truth: truth.map(|p| [p.x, p.y, p.yaw]),
        }
    }
}

/// Lines as JSON Lines text (one object per line, NaN ranges written as `null`).
pub fn to_jsonl<T: Serialize>(lines: &[T]) -> Result<String, serde_json::Error> {
    let mut out = String::new();
    for line in lines {
        out += &serde_json::to_string(line)?;
        out.push('\n');
    }
    Ok(out)
}

/// Reads and parses a whole log; see [`parse_log`].
pub fn read_log(path: &Path) -> Result<Vec<LogLine>, ReplayError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| ReplayError::Read { path: path.into(), source })?;
    parse_log(&text, path)
}

/// Parses JSON Lines text; blank lines are skipped, every other line must be a [`LogLine`].
/// `path` only labels errors, which name the 1-based line number and the field.
pub fn parse_log(text: &str, path: &Path) -> Result<Vec<LogLine>, ReplayError> {
    let lines: Vec<LogLine> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(index, l)| parse_line(l, index + 1, path))
        .collect::<Result<_, _>>()?;
    if lines.is_empty() {
        return Err(ReplayError::Empty { path: path.into() });
    }
    Ok(lines)
}

/// Parses one line (`number` is 1-based, for errors).
pub fn parse_line(text: &str, number: usize, path: &Path) -> Result<LogLine, ReplayError> {
    let value: Value = serde_json::from_str(&python_tokens_to_json(text)).map_err(|e| {
        ReplayError::Syntax { path: path.into(), line: number, column: e.column(), message: e.to_string() }
    })?;
    let Value::Object(object) = value else {
        return Err(ReplayError::Syntax {
            path: path.into(),
            line: number,
            column: 1,
            message: format!("expected an object {{\"t\": …, \"odom\": …}}, found {}", preview(&value)),
        });
    };
    let fields = Fields { object: &object, path, line: number };
    let line = LogLine {
        t: fields.number("t", "a finite time in seconds")?,
        odom: fields.pose("odom")?,
        ranges: fields.ranges()?,
        angle_min: fields.number("angle_min", "a finite angle in radians")? as f32,
        angle_increment: fields.number("angle_increment", "a finite angle in radians")? as f32,
        range_min: fields.number("range_min", "a finite range in metres")? as f32,
        range_max: fields.number("range_max", "a finite range in metres")? as f32,
        truth: match object.get("truth") {
            None | Some(Value::Null) => None,
            Some(_) => Some(fields.pose("truth")?),
        },
    };
    if !(line.range_min >= 0.0 && line.range_max > line.range_min) {
        let found = format!("range_min {} and range_max {}", line.range_min, line.range_max);
        return Err(fields.error("range_max", "0 ≤ range_min < range_max", found));
    }
    Ok(line)
}

/// Typed access to one line's fields, with errors that name the line and the field.
struct Fields<'a> {
    object: &'a Map<String, Value>,
    path: &'a Path,
    line: usize,
}

impl Fields<'_> {
    fn error(&self, field: &'static str, expected: &'static str, found: String) -> ReplayError {
        ReplayError::Field { path: self.path.into(), line: self.line, field, expected, found }
    }

    fn get(&self, field: &'static str, expected: &'static str) -> Result<&Value, ReplayError> {
        self.object.get(field).ok_or_else(|| self.error(field, expected, "no such field".into()))
    }

    fn number(&self, field: &'static str, expected: &'static str) -> Result<f64, ReplayError> {
        let value = self.get(field, expected)?;
        match value.as_f64() {
            Some(v) if v.is_finite() => Ok(v),
            _ => Err(self.error(field, expected, preview(value))),
        }
    }

    fn pose(&self, field: &'static str) -> Result<[f32; 3], ReplayError> {
        const EXPECTED: &str = "an array of 3 finite numbers [x m, y m, θ rad]";
        let value = self.get(field, EXPECTED)?;
        let numbers: Option<Vec<f32>> = value
            .as_array()
            .filter(|a| a.len() == 3)
            .and_then(|a| a.iter().map(|v| v.as_f64().filter(|v| v.is_finite()).map(|v| v as f32)).collect());
        match numbers.as_deref() {
            Some(&[x, y, yaw]) => Ok([x, y, yaw]),
            _ => Err(self.error(field, EXPECTED, preview(value))),
        }
    }

    fn ranges(&self) -> Result<Vec<f32>, ReplayError> {
        const EXPECTED: &str =
            "a non-empty array of ranges in metres (numbers; null or \"nan\" for no reading)";
        let value = self.get("ranges", EXPECTED)?;
        let Some(items) = value.as_array().filter(|a| !a.is_empty()) else {
            return Err(self.error("ranges", EXPECTED, preview(value)));
        };
        if !crate::limits::BEAMS.contains(items.len()) {
            return Err(self.error(
                "ranges",
                crate::limits::BEAMS.expected,
                format!("{} ranges", items.len()),
            ));
        }
        items
            .iter()
            .map(|v| match v {
                Value::Null => Some(f32::NAN),
                Value::Number(n) => n.as_f64().map(|r| r as f32),
                Value::String(s) => s.trim().parse::<f32>().ok(),
                _ => None,
            })
            .enumerate()
            .map(|(i, r)| {
                r.ok_or_else(|| {
                    self.error("ranges", EXPECTED, format!("{} at index {i}", preview(&items[i])))
                })
            })
            .collect()
    }
}

/// A short rendering of a JSON value for error messages.
fn preview(value: &Value) -> String {
    let text = value.to_string();
    match text.char_indices().nth(60) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text,
    }
}

/// Python's `json.dumps` writes non-finite floats as bare `NaN`, `Infinity` and `-Infinity`,
/// which JSON forbids; outside strings they become `null`, `"inf"` and `"-inf"`.
fn python_tokens_to_json(line: &str) -> Cow<'_, str> {
    if !line.contains("NaN") && !line.contains("Infinity") {
        return Cow::Borrowed(line);
    }
    let mut out = String::with_capacity(line.len() + 16);
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = line;
    while let Some(c) = rest.chars().next() {
        if in_string {
            (in_string, escaped) = (escaped || c != '"', !escaped && c == '\\');
        } else if c == '"' {
            in_string = true;
        } else {
            let replaced = [("NaN", "null"), ("-Infinity", "\"-inf\""), ("Infinity", "\"inf\"")]
                .into_iter()
                .find(|(token, _)| rest.starts_with(token));
            if let Some((token, json)) = replaced {
                out += json;
                rest = &rest[token.len()..];
                continue;
            }
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"{"t": 0.6, "odom": [1, 2, 0.5], "ranges": [1.0, null, "inf", 2.5], "angle_min": -1.0,
        "angle_increment": 0.5, "range_min": 0.05, "range_max": 5.6, "frame_id": "laser"}"#;

    fn one_line(text: &str) -> String {
        text.replace('\n', " ")
    }

    #[test]
    fn log_line_parses_ros_fields_and_non_finite_ranges() {
        let line = parse_line(&one_line(GOOD), 1, Path::new("a.jsonl")).expect("valid line");
        assert_eq!(line.odom, [1.0, 2.0, 0.5]);
        assert_eq!(line.truth, None, "truth is optional");
        assert!(line.ranges[1].is_nan(), "null reads as NaN: {:?}", line.ranges);
        assert_eq!(line.ranges[2], f32::INFINITY, "\"inf\" reads as +∞");
        assert_eq!(line.scan().angle_increment_rad, 0.5);
    }

    #[test]
    fn log_line_accepts_python_nan_and_infinity() {
        let text = one_line(GOOD).replace("null", "NaN").replace("\"inf\"", "-Infinity");
        let text = text.replace("\"laser\"", "\"NaN Infinity\"");
        let line = parse_line(&text, 1, Path::new("a.jsonl")).expect("Python's json.dumps output loads");
        assert!(line.ranges[1].is_nan() && line.ranges[2] == f32::NEG_INFINITY, "{:?}", line.ranges);
    }

    #[test]
    fn log_line_errors_name_line_and_field() {
        let bad_odom = one_line(GOOD).replace("[1, 2, 0.5]", "[1, 2]");
        let err =
            parse_line(&bad_odom, 7, Path::new("run.jsonl")).expect_err("odom has 2 values").to_string();
        assert!(err.contains("run.jsonl:7") && err.contains("`odom`"), "got: {err}");
        let no_ranges = one_line(GOOD).replace("\"ranges\"", "\"rangez\"");
        let err = parse_line(&no_ranges, 3, Path::new("run.jsonl")).expect_err("no ranges").to_string();
        assert!(
            err.contains(":3:") && err.contains("`ranges`") && err.contains("no such field"),
            "got: {err}"
        );
        let bad_range = one_line(GOOD).replace("2.5]", "true]");
        let err = parse_line(&bad_range, 2, Path::new("r")).expect_err("bool range").to_string();
        assert!(err.contains("at index 3"), "the bad element is located: {err}");
        let err = parse_line("{\"t\": 1,", 4, Path::new("r")).expect_err("truncated line").to_string();
        assert!(err.starts_with("r:4:"), "syntax errors carry the line: {err}");
    }

    #[test]
    fn log_round_trips_through_jsonl() {
        let mut line = parse_line(&one_line(GOOD), 1, Path::new("a")).expect("valid");
        line.truth = Some([3.0, 4.0, -1.0]);
        let text = to_jsonl(&[line.clone(), line.clone()]).expect("serialises");
        let back = parse_log(&format!("{text}\n\n"), Path::new("a")).expect("parses back");
        assert_eq!(back.len(), 2, "blank lines are skipped");
        assert_eq!(back[0].truth, line.truth);
        assert!(back[0].ranges[1].is_nan(), "NaN survives as null");
        assert!(matches!(parse_log("\n", Path::new("e")), Err(ReplayError::Empty { .. })));
    }
}
