//! Everything that can go wrong reading a bag: the file (unreadable, not MCAP, cut short,
//! corrupt), a topic (absent, of another type) or one message (malformed or unusable). Every
//! error names the file; those about a topic or a message name the topic too.

use mcap::McapError;
use std::path::PathBuf;
use thiserror::Error;

/// One message is not what its type says: the field, what was expected and what was found.
#[derive(Clone, Debug, PartialEq, Error)]
#[error("field `{field}`: expected {expected}, found {found}")]
pub struct MessageError {
    pub field: &'static str,
    pub expected: String,
    pub found: String,
}

/// Errors of the `replay::bag` module.
#[derive(Debug, Error)]
pub enum BagError {
    /// The file could not be read.
    #[error("cannot read bag {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The file does not start with the MCAP magic bytes.
    #[error(
        "{path} is not an MCAP file (it does not start with the MCAP magic bytes); expected a rosbag2 \
         recording made with `ros2 bag record -s mcap` (a .db3 bag converts with `ros2 bag convert`)"
    )]
    NotMcap { path: PathBuf },

    /// The file ends inside a record, as a recording that was killed does.
    #[error(
        "{path} ends in the middle of a record: the recording was cut short; \
         `mcap recover {path} -o repaired.mcap` saves what was written"
    )]
    Truncated {
        path: PathBuf,
        #[source]
        source: McapError,
    },

    /// The MCAP structure is broken (bad CRC, bad record, undecodable chunk).
    #[error("{path} is a corrupt MCAP file: {source}")]
    Corrupt {
        path: PathBuf,
        #[source]
        source: McapError,
    },

    /// Chunks compressed with something other than zstd (rosbag2 writes zstd or nothing).
    #[error(
        "{path} compresses its chunks with `{format}`; expected zstd or no compression (rosbag2's \
         choices): re-compress it with zstd, e.g. with the mcap CLI's `compress` command"
    )]
    Compression { path: PathBuf, format: String },

    /// No message on the topic the flag names.
    #[error("{path} has no message on topic {topic} (set by {flag}); topics with messages: {available}")]
    MissingTopic { path: PathBuf, topic: String, flag: &'static str, available: String },

    /// The topic carries another message type, or is not CDR-encoded.
    #[error(
        "{path}: topic {topic} (set by {flag}) carries {found}; expected {expected} (message encoding `cdr`)"
    )]
    WrongType { path: PathBuf, topic: String, flag: &'static str, expected: &'static str, found: String },

    /// One message cannot be decoded or used; `index` is 1-based, in file order on its topic.
    #[error("{path}: topic {topic}, message {index}: {source}")]
    Message {
        path: PathBuf,
        topic: String,
        index: usize,
        #[source]
        source: MessageError,
    },

    /// No scan was taken while odometry was recorded, so none has an odometry pose.
    #[error(
        "{path}: no scan on {scan_topic} (stamps {scans}) falls within the odometry on {odom_topic} \
         (stamps {odometry}); expected both recorded over the same time (header stamps)"
    )]
    NoOverlap { path: PathBuf, scan_topic: String, odom_topic: String, scans: String, odometry: String },
}
