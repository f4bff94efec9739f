//! The backend stage process (see `supermvo_pipeline::backend`); started by the supervisor.

supermvo_pipeline::stage_main!(backend);
