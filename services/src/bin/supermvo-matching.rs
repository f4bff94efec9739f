//! The matching stage process (see `supermvo_pipeline::matching`); started by the supervisor.

supermvo_pipeline::stage_main!(matching);
