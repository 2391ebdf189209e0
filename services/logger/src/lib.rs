//! The motm logger: taps every iceoryx2 service of a running stack and writes a chunked MCAP
//! file that opens in Foxglove (foxglove protobuf schemas for the 3D view and the camera, JSON
//! channels with a jsonschema for everything else), and reads such files back for
//! `motm log info` and `motm log check`.
//!
//! - [`recorder`]: the pure step, samples → records (derived 3D channels, decimation).
//! - [`channels`]: records → channels and encoded messages, shared by the sinks.
//! - [`sink`]: encoded messages → MCAP channels and chunks.
//! - [`live`]: encoded messages → the Foxglove WebSocket live view.
//! - [`inspect`]: scanning a (possibly cut-off) log; [`protobuf_check`]: decoding with the
//!   schema stored in the file.
//! - [`replay_log`]: the raw samples and cycle records that `motm replay` reads.
//! - [`foxglove`], [`json`]: the message encodings.
//! - [`service`]: the `logger` process (the taps, the sinks and their loop).

pub mod channels;
pub mod foxglove;
pub mod inspect;
pub mod json;
pub mod live;
pub mod protobuf_check;
pub mod recorder;
pub mod replay_log;
pub mod service;
pub mod sink;
pub mod writeback;

pub use channels::ChannelRegistry;
pub use inspect::{LogSummary, scan};
pub use live::{LiveConfig, LiveSink};
pub use recorder::{LoggerConfig, Record, Recorder, SceneLayout};
pub use sink::McapSink;
pub use writeback::WritebackFile;
