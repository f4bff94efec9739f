//! The ingest stage process (see `supermvo_services::ingest`); started by the supervisor.

supermvo_services::stage_main!(ingest);
