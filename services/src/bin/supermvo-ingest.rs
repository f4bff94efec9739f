//! The ingest stage process (see `supermvo_pipeline::ingest`); started by the supervisor.

supermvo_pipeline::stage_main!(ingest);
