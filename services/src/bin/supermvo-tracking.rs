//! The tracking stage process (see `supermvo_services::tracking`); started by the supervisor.

supermvo_services::stage_main!(tracking);
