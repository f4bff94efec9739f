//! The byte layouts of the messages that readers outside this workspace decode (the Python
//! subscriber in `examples/python/`, any C or ctypes client), checked at compile time against
//! [`SCHEMA_VERSION`]: a change to one of these structs fails the build here until the sizes
//! and offsets below, the table in `docs/daemon.md` ("Message layouts") and the example's
//! ctypes definitions are updated together, and the schema version is raised.
//!
//! All fields are little-endian (the only byte order iceoryx2 shares memory in here) and
//! naturally aligned; `#[repr(C)]` puts them in declaration order with padding where shown.

use crate::{
    BackendState, BackfilledPose, CorrectionMsg, FrameHeader, PoseMsg, Progress, SCHEMA_VERSION,
};
use std::mem::{align_of, offset_of, size_of};

/// One field of a documented layout: name, byte offset, size in bytes.
pub type Field = (&'static str, usize, usize);

/// `(iceoryx2 type name, size, alignment, fields)` of every documented message, in the order
/// of the table in `docs/daemon.md`.
pub fn documented() -> Vec<(&'static str, usize, usize, Vec<Field>)> {
    vec![
        (
            "supermvo::FrameHeader",
            size_of::<FrameHeader>(),
            align_of::<FrameHeader>(),
            vec![
                ("schema", offset_of!(FrameHeader, schema), 4),
                ("status", offset_of!(FrameHeader, status), 4),
                ("seq", offset_of!(FrameHeader, seq), 8),
                ("frame", offset_of!(FrameHeader, frame), 8),
                ("stamp", offset_of!(FrameHeader, stamp), 8),
                ("width", offset_of!(FrameHeader, width), 4),
                ("height", offset_of!(FrameHeader, height), 4),
                ("reference", offset_of!(FrameHeader, reference), 8),
                ("count", offset_of!(FrameHeader, count), 4),
                ("dim", offset_of!(FrameHeader, dim), 4),
                ("t_ns", offset_of!(FrameHeader, t_ns), 40),
            ],
        ),
        (
            "supermvo::PoseMsg",
            size_of::<PoseMsg>(),
            align_of::<PoseMsg>(),
            vec![
                ("state", offset_of!(PoseMsg, state), 4),
                ("has_pose", offset_of!(PoseMsg, has_pose), 4),
                ("t_world_cam", offset_of!(PoseMsg, t_world_cam), 96),
                ("keyframe", offset_of!(PoseMsg, keyframe), 4),
                ("keypoints", offset_of!(PoseMsg, keypoints), 4),
                ("matches", offset_of!(PoseMsg, matches), 4),
                ("inliers", offset_of!(PoseMsg, inliers), 4),
                ("landmarks", offset_of!(PoseMsg, landmarks), 8),
                ("reference", offset_of!(PoseMsg, reference), 8),
                ("match_next", offset_of!(PoseMsg, match_next), 4),
                ("scale", offset_of!(PoseMsg, scale), 8),
                ("backfilled_count", offset_of!(PoseMsg, backfilled_count), 4),
                ("corrections", offset_of!(PoseMsg, corrections), 4),
                ("backfilled", offset_of!(PoseMsg, backfilled), 16 * 104),
            ],
        ),
        (
            "supermvo::BackfilledPose",
            size_of::<BackfilledPose>(),
            align_of::<BackfilledPose>(),
            vec![
                ("seq", offset_of!(BackfilledPose, seq), 8),
                ("t_world_cam", offset_of!(BackfilledPose, t_world_cam), 96),
            ],
        ),
        (
            "supermvo::Progress",
            size_of::<Progress>(),
            align_of::<Progress>(),
            vec![
                ("stage", offset_of!(Progress, stage), 4),
                ("worker", offset_of!(Progress, worker), 4),
                ("pid", offset_of!(Progress, pid), 4),
                ("event", offset_of!(Progress, event), 4),
                ("seq", offset_of!(Progress, seq), 8),
                ("frame", offset_of!(Progress, frame), 8),
                ("status", offset_of!(Progress, status), 4),
                ("queue", offset_of!(Progress, queue), 4),
                ("t_in_ns", offset_of!(Progress, t_in_ns), 8),
                ("t_out_ns", offset_of!(Progress, t_out_ns), 8),
                ("t_capture_ns", offset_of!(Progress, t_capture_ns), 8),
                ("cpu_ns", offset_of!(Progress, cpu_ns), 8),
            ],
        ),
        (
            "supermvo::BackendState",
            size_of::<BackendState>(),
            align_of::<BackendState>(),
            vec![
                ("seq", offset_of!(BackendState, seq), 8),
                ("frame", offset_of!(BackendState, frame), 8),
                ("has_pose", offset_of!(BackendState, has_pose), 4),
                ("corrections", offset_of!(BackendState, corrections), 4),
                ("t_world_cam", offset_of!(BackendState, t_world_cam), 96),
                ("scale", offset_of!(BackendState, scale), 8),
                ("recorded", offset_of!(BackendState, recorded), 8),
                ("state", offset_of!(BackendState, state), 4),
                ("finished", offset_of!(BackendState, finished), 4),
            ],
        ),
        (
            "supermvo::CorrectionMsg",
            size_of::<CorrectionMsg>(),
            align_of::<CorrectionMsg>(),
            vec![
                ("closed", offset_of!(CorrectionMsg, closed), 4),
                ("corrections", offset_of!(CorrectionMsg, corrections), 4),
                ("scale", offset_of!(CorrectionMsg, scale), 8),
                ("rotation", offset_of!(CorrectionMsg, rotation), 72),
                ("translation", offset_of!(CorrectionMsg, translation), 24),
                ("loop_query", offset_of!(CorrectionMsg, loop_query), 8),
                ("loop_match", offset_of!(CorrectionMsg, loop_match), 8),
            ],
        ),
    ]
}

// The layouts of schema version 4. Raising SCHEMA_VERSION means a layout changed: check
// every line below against the structs, then docs/daemon.md and examples/python/.
const _: () = {
    assert!(
        SCHEMA_VERSION == 4,
        "schema changed: update the layout checks, docs/daemon.md and examples/python"
    );
    assert!(size_of::<FrameHeader>() == 96 && align_of::<FrameHeader>() == 8);
    assert!(offset_of!(FrameHeader, seq) == 8 && offset_of!(FrameHeader, frame) == 16);
    assert!(offset_of!(FrameHeader, stamp) == 24 && offset_of!(FrameHeader, width) == 32);
    assert!(offset_of!(FrameHeader, reference) == 40 && offset_of!(FrameHeader, count) == 48);
    assert!(offset_of!(FrameHeader, dim) == 52 && offset_of!(FrameHeader, t_ns) == 56);
    assert!(size_of::<PoseMsg>() == 1824 && align_of::<PoseMsg>() == 8);
    assert!(offset_of!(PoseMsg, has_pose) == 4 && offset_of!(PoseMsg, t_world_cam) == 8);
    assert!(offset_of!(PoseMsg, keyframe) == 104 && offset_of!(PoseMsg, inliers) == 116);
    assert!(offset_of!(PoseMsg, landmarks) == 120 && offset_of!(PoseMsg, reference) == 128);
    assert!(offset_of!(PoseMsg, match_next) == 136 && offset_of!(PoseMsg, scale) == 144);
    assert!(offset_of!(PoseMsg, backfilled_count) == 152);
    assert!(offset_of!(PoseMsg, corrections) == 156);
    assert!(offset_of!(PoseMsg, backfilled) == 160 && crate::MAX_BACKFILLED == 16);
    assert!(size_of::<BackfilledPose>() == 104 && align_of::<BackfilledPose>() == 8);
    assert!(offset_of!(BackfilledPose, t_world_cam) == 8);
    assert!(size_of::<Progress>() == 72 && align_of::<Progress>() == 8);
    assert!(offset_of!(Progress, seq) == 16 && offset_of!(Progress, status) == 32);
    assert!(offset_of!(Progress, t_in_ns) == 40 && offset_of!(Progress, cpu_ns) == 64);
    assert!(size_of::<BackendState>() == 144 && align_of::<BackendState>() == 8);
    assert!(offset_of!(BackendState, t_world_cam) == 24 && offset_of!(BackendState, scale) == 120);
    assert!(offset_of!(BackendState, recorded) == 128 && offset_of!(BackendState, finished) == 140);
    assert!(offset_of!(BackendState, corrections) == 20);
    assert!(size_of::<CorrectionMsg>() == 128 && align_of::<CorrectionMsg>() == 8);
    assert!(offset_of!(CorrectionMsg, scale) == 8 && offset_of!(CorrectionMsg, rotation) == 16);
    assert!(offset_of!(CorrectionMsg, translation) == 88);
    assert!(offset_of!(CorrectionMsg, loop_query) == 112);
};

#[cfg(test)]
mod tests {
    use super::*;

    /// The table in docs/daemon.md is this function's output: every row there matches a
    /// field here (name, offset, size), so the document cannot drift from the structs.
    #[test]
    fn the_documented_table_matches_the_structs() {
        let doc_path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/daemon.md");
        let doc = std::fs::read_to_string(doc_path).expect("docs/daemon.md");
        for (name, size, align, fields) in documented() {
            let heading = format!("`{name}` ({size} bytes, alignment {align})");
            let mut end = doc
                .find(&heading)
                .unwrap_or_else(|| panic!("docs/daemon.md lacks {heading}"));
            for (field, offset, bytes) in fields {
                let row = format!("| `{field}` | {offset} | {bytes} |");
                let at = doc[end..]
                    .find(&row)
                    .unwrap_or_else(|| panic!("docs/daemon.md: {name} lacks row {row}"));
                end += at + row.len();
            }
        }
    }

    #[test]
    fn fields_do_not_overlap_and_fit() {
        for (name, size, _, fields) in documented() {
            for w in fields.windows(2) {
                assert!(
                    w[0].1 + w[0].2 <= w[1].1,
                    "{name}: {} overlaps {}",
                    w[0].0,
                    w[1].0
                );
            }
            let last = fields.last().unwrap();
            assert!(last.1 + last.2 <= size, "{name}: {} past the end", last.0);
        }
    }
}
