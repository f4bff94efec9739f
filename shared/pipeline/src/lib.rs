//! The SuPerMVO pipeline library, shared by the `supermvo` CLI and the stage processes:
//! the front end and tracker built from the configuration ([`features::extractor`],
//! [`matching::matcher`], [`tracking::tracker_config`]), each stage (ingest, features,
//! matching, tracking, back end) exchanging frames, features, matches and poses over iceoryx2
//! shared memory, the supervisor that starts, watches, restarts and measures them, the
//! read-only monitor, and the back end's frame records.
//!
//! The stage binaries (crate `supermvo-services`) only call [`stage_main!`] or the supervisor;
//! the CLI uses the same library without linking the stage binaries' crate. The stages run the same library types as `supermvo run --mode inprocess`
//! ([`supermvo_vo::pipeline::VoPipeline`]), so both modes give the same trajectory.

pub mod backend;
pub mod bench_ipc;
pub mod common;
pub mod features;
pub mod frame_log;
pub mod inbox;
pub mod ingest;
pub mod log_relay;
pub mod loop_closing;
pub mod loop_feedback;
pub mod mapping_codec;
pub mod matching;
pub mod monitor;
pub mod remote_mapping;
pub mod supervisor;
pub mod tracking;
pub mod viewer;
pub mod views;
