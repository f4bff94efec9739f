//! The features stage process (see `supermvo_pipeline::features`); started by the supervisor.

supermvo_pipeline::stage_main!(features);
