//! The matching stage process (see `supermvo_services::matching`); started by the supervisor.

supermvo_services::stage_main!(matching);
