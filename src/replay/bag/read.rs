//! A rosbag2 MCAP file as the log lines `apfn localize` runs on: every LaserScan on the scan
//! topic becomes one [`LogLine`] stamped with its header stamp, with the odometry pose
//! interpolated at that stamp ([`OdometryTrack`]). Scans outside the odometry's time span are
//! dropped and counted. [`parse_bag`] works on bytes and returns an error, never a panic, on any
//! input; [`read_bag`] reads the file first.

use crate::replay::LogLine;
use crate::replay::bag::error::{BagError, MessageError};
use crate::replay::bag::messages::{LASER_SCAN, LaserScanMsg, ODOMETRY, OdometryMsg};
use crate::replay::bag::odometry_track::OdometryTrack;
use mcap::sans_io::{LinearReaderOptions, MessageReadEvent, MessageReader};
use mcap::{McapError, McapResult, Message};
use std::collections::BTreeMap;
use std::path::Path;

/// The topics holding the scans and the odometry (defaults: `/scan`, `/odom`).
#[derive(Clone, Debug, PartialEq)]
pub struct BagTopics {
    pub scan: String,
    pub odom: String,
}

impl Default for BagTopics {
    fn default() -> Self {
        Self { scan: "/scan".into(), odom: "/odom".into() }
    }
}

/// What a bag gave: one line per usable scan and what was read to make them.
#[derive(Clone, Debug, PartialEq)]
pub struct BagLog {
    /// One line per scan within the odometry's time span, in stamp order; `truth` is `None`.
    pub lines: Vec<LogLine>,
    /// Scans on the scan topic, including those dropped for lack of odometry.
    pub scans: usize,
    /// Messages on the odometry topic.
    pub odometry: usize,
    /// `header.frame_id` of the first scan (the laser's frame).
    pub scan_frame: String,
    /// `header.frame_id` and `child_frame_id` of the first odometry message.
    pub odom_frames: (String, String),
}

impl BagLog {
    /// Scans dropped because no odometry brackets their stamp.
    pub fn dropped(&self) -> usize {
        self.scans - self.lines.len()
    }
}

/// Reads the file at `path`, then [`parse_bag`].
pub fn read_bag(path: &Path, topics: &BagTopics) -> Result<BagLog, BagError> {
    let bytes = std::fs::read(path).map_err(|source| BagError::Read { path: path.into(), source })?;
    parse_bag(&bytes, path, topics)
}

/// Decodes the scans and odometry of an MCAP file held in `bytes` and pairs them; `path` only
/// labels errors. Reads chunked or unchunked files with uncompressed or zstd chunks (the default
/// of `ros2 bag record -s mcap`) and checks chunk CRCs.
pub fn parse_bag(bytes: &[u8], path: &Path, topics: &BagTopics) -> Result<BagLog, BagError> {
    let messages = TopicMessages::read(bytes, path, topics)?;
    let missing = |topic: &str, flag| BagError::MissingTopic {
        path: path.into(),
        topic: topic.into(),
        flag,
        available: messages.topic_list(),
    };
    let (Some(first_scan), Some(first_odom)) = (messages.scans.first(), messages.odometry.first()) else {
        return Err(if messages.scans.is_empty() {
            missing(&topics.scan, "--scan-topic")
        } else {
            missing(&topics.odom, "--odom-topic")
        });
    };
    let message_error = |topic: &str, index: usize, source| BagError::Message {
        path: path.into(),
        topic: topic.into(),
        index: index + 1,
        source,
    };
    let samples = messages
        .odometry
        .iter()
        .enumerate()
        .map(|(i, odom)| match odom.pose2() {
            Some(pose) => Ok((odom.header.stamp_s(), pose)),
            None => Err(message_error(&topics.odom, i, unusable_pose(odom))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let track = OdometryTrack::new(samples);
    for (i, scan) in messages.scans.iter().enumerate() {
        check_scan(scan).map_err(|e| message_error(&topics.scan, i, e))?;
    }

    let mut scans: Vec<&LaserScanMsg> = messages.scans.iter().collect();
    scans.sort_by(|a, b| a.header.stamp_s().total_cmp(&b.header.stamp_s()));
    let lines: Vec<LogLine> = scans
        .iter()
        .filter_map(|scan| {
            let t = scan.header.stamp_s();
            let odom = track.at(t)?;
            Some(LogLine {
                t,
                odom: [odom.x, odom.y, odom.yaw],
                ranges: scan.ranges.clone(),
                angle_min: scan.angle_min,
                angle_increment: scan.angle_increment,
                range_min: scan.range_min,
                range_max: scan.range_max,
                truth: None,
            })
        })
        .collect();
    if lines.is_empty() {
        let span = |first: f64, last: f64| format!("{first:.3}–{last:.3} s");
        let (odom_first, odom_last) = track.span_s().unwrap_or_default();
        let scan_first = scans.first().map_or(0.0, |s| s.header.stamp_s());
        let scan_last = scans.last().map_or(0.0, |s| s.header.stamp_s());
        return Err(BagError::NoOverlap {
            path: path.into(),
            scan_topic: topics.scan.clone(),
            odom_topic: topics.odom.clone(),
            scans: span(scan_first, scan_last),
            odometry: span(odom_first, odom_last),
        });
    }
    Ok(BagLog {
        lines,
        scans: messages.scans.len(),
        odometry: track.len(),
        scan_frame: first_scan.header.frame_id.clone(),
        odom_frames: (first_odom.header.frame_id.clone(), first_odom.child_frame_id.clone()),
    })
}

/// The same checks a JSON Lines log line gets: ranges present, range limits and angles finite,
/// 0 ≤ range_min < range_max. Individual ranges may be NaN or ±∞ (REP 117: no return).
fn check_scan(scan: &LaserScanMsg) -> Result<(), MessageError> {
    let error =
        |field, expected: &str, found: String| MessageError { field, expected: expected.into(), found };
    if scan.ranges.is_empty() {
        return Err(error("ranges", "at least one range", "an empty scan".into()));
    }
    for (field, v) in [("angle_min", scan.angle_min), ("angle_increment", scan.angle_increment)] {
        if !v.is_finite() {
            return Err(error(field, "a finite angle in radians", v.to_string()));
        }
    }
    if !(scan.range_min >= 0.0 && scan.range_max > scan.range_min && scan.range_max.is_finite()) {
        let found = format!("range_min {} and range_max {}", scan.range_min, scan.range_max);
        return Err(error("range_max", "finite limits with 0 ≤ range_min < range_max", found));
    }
    Ok(())
}

fn unusable_pose(odom: &OdometryMsg) -> MessageError {
    MessageError {
        field: "pose.pose",
        expected: "a finite position and a non-zero orientation quaternion".into(),
        found: format!("position {:?}, orientation {:?}", odom.position, odom.orientation),
    }
}

/// The decoded messages of the two topics, and every topic's type and message count.
struct TopicMessages {
    scans: Vec<LaserScanMsg>,
    odometry: Vec<OdometryMsg>,
    /// topic → (schema name, messages)
    topics: BTreeMap<String, (String, usize)>,
}

impl TopicMessages {
    fn read(bytes: &[u8], path: &Path, topics: &BagTopics) -> Result<Self, BagError> {
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(BagError::NotMcap { path: path.into() });
        }
        let mcap_error = |source| match source {
            McapError::UnexpectedEof | McapError::UnexpectedEoc => {
                BagError::Truncated { path: path.into(), source }
            }
            McapError::UnsupportedCompression(format) => BagError::Compression { path: path.into(), format },
            source => BagError::Corrupt { path: path.into(), source },
        };
        let mut out = Self { scans: Vec::new(), odometry: Vec::new(), topics: BTreeMap::new() };
        for message in mcap_messages(bytes) {
            let message = message.map_err(mcap_error)?;
            let topic = &message.channel.topic;
            let entry = out.topics.entry(topic.clone()).or_insert_with(|| (schema_name(&message), 0));
            entry.1 += 1;
            let index = entry.1 - 1;
            let decode_error = |source| BagError::Message {
                path: path.into(),
                topic: topic.clone(),
                index: index + 1,
                source,
            };
            if *topic == topics.scan {
                check_type(&message, LASER_SCAN, "--scan-topic", path)?;
                out.scans.push(LaserScanMsg::decode(&message.data).map_err(decode_error)?);
            }
            if *topic == topics.odom {
                check_type(&message, ODOMETRY, "--odom-topic", path)?;
                out.odometry.push(OdometryMsg::decode(&message.data).map_err(decode_error)?);
            }
        }
        Ok(out)
    }

    /// "/odom (nav_msgs/msg/Odometry, 12 messages), …" or "none".
    fn topic_list(&self) -> String {
        let list: Vec<String> = self
            .topics
            .iter()
            .map(|(topic, (schema, n))| {
                format!("{topic} ({schema}, {n} message{})", if *n == 1 { "" } else { "s" })
            })
            .collect();
        if list.is_empty() { "none".into() } else { list.join(", ") }
    }
}

/// The messages of an MCAP file in file order, chunk CRCs checked. No record or decompressed
/// chunk may claim more than 64 MiB or 8 × the file's size, whichever is larger: a damaged length
/// field is then an error rather than an allocation of exabytes (mcap 0.26's `MessageStream` sets
/// no bound on a chunk's decompressed size), while real chunks fit — rosbag2 closes a chunk at
/// 768 KiB, and a larger one holds a single large message that the file holds too, compressed.
fn mcap_messages(bytes: &[u8]) -> impl Iterator<Item = McapResult<Message<'static>>> + '_ {
    let limit = bytes.len().saturating_mul(8).max(64 << 20);
    let options =
        LinearReaderOptions::default().with_validate_chunk_crcs(true).with_record_length_limit(limit);
    let mut reader = MessageReader::new_with_options(options);
    let mut rest = bytes;
    std::iter::from_fn(move || {
        loop {
            match reader.next_event()? {
                Ok(MessageReadEvent::ReadRequest(wanted)) => {
                    let (now, later) = rest.split_at(wanted.min(rest.len()));
                    reader.insert(now.len()).copy_from_slice(now);
                    reader.notify_read(now.len());
                    rest = later;
                }
                Ok(MessageReadEvent::Message(message)) => return Some(Ok(message)),
                Err(e) => return Some(Err(e)),
            }
        }
    })
}

fn schema_name(message: &Message) -> String {
    message.channel.schema.as_ref().map_or_else(|| "no schema".into(), |s| s.name.clone())
}

fn check_type(
    message: &Message,
    expected: &'static str,
    flag: &'static str,
    path: &Path,
) -> Result<(), BagError> {
    let (schema, encoding) = (schema_name(message), &message.channel.message_encoding);
    if schema == expected && encoding == "cdr" {
        return Ok(());
    }
    Err(BagError::WrongType {
        path: path.into(),
        topic: message.channel.topic.clone(),
        flag,
        expected,
        found: format!("{schema} (message encoding `{encoding}`)"),
    })
}
