//! The tracking stage process (see `supermvo_pipeline::tracking`); started by the supervisor.

supermvo_pipeline::stage_main!(tracking);
