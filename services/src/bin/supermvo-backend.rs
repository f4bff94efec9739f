//! The backend stage process (see `supermvo_services::backend`); started by the supervisor.

supermvo_services::stage_main!(backend);
