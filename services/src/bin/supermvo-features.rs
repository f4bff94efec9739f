//! The features stage process (see `supermvo_services::features`); started by the supervisor.

supermvo_services::stage_main!(features);
