//! The SuPerMVO pipeline as processes: one binary per stage (ingest, features, matching,
//! tracking, back end) exchanging frames, features, matches and poses over iceoryx2 shared
//! memory, and the supervisor that starts, watches, restarts and measures them.
//!
//! Each stage is library code here; each binary's `main` only parses its arguments and calls
//! it. The stages run the same library types as `supermvo run --mode inprocess`
//! ([`supermvo_vo::tracker::VoPipeline`]), so both modes give the same trajectory.

pub mod backend;
pub mod bench_ipc;
pub mod common;
pub mod features;
pub mod inbox;
pub mod ingest;
pub mod matching;
pub mod monitor;
pub mod supervisor;
pub mod tracking;
