//! The stages' warnings and errors on the supervisor's terminal: each stage writes its log
//! to `logs/<stage>-<worker>.log`, and the supervisor echoes the new WARN and ERROR lines of
//! every log to its own stderr, prefixed with the stage, so that a skipped frame or a failing
//! model is seen where the run was started and not only in a file.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Read positions in the stage logs.
#[derive(Debug, Default)]
pub struct LogRelay {
    /// Per log file, how far it has been read.
    read_to: BTreeMap<PathBuf, u64>,
}

impl LogRelay {
    /// Starts following `path` from its current end (what an earlier run or an earlier
    /// process of the stage wrote is not repeated); a file already followed keeps its place.
    pub fn follow(&mut self, path: &Path) {
        let end = std::fs::metadata(path).map_or(0, |m| m.len());
        self.read_to.entry(path.to_path_buf()).or_insert(end);
    }

    /// The WARN and ERROR lines written to the followed logs since the last call, each as
    /// `[<log name>] <line>`.
    pub fn new_lines(&mut self) -> Vec<String> {
        let mut lines = Vec::new();
        for (path, pos) in self.read_to.iter_mut() {
            let Ok(mut file) = std::fs::File::open(path) else {
                continue;
            };
            let mut text = String::new();
            if file.seek(SeekFrom::Start(*pos)).is_err() || file.read_to_string(&mut text).is_err()
            {
                continue;
            }
            // only whole lines; a line still being written is read next time
            let complete = text.rfind('\n').map_or(0, |i| i + 1);
            *pos += complete as u64;
            let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("stage");
            lines.extend(
                text[..complete]
                    .lines()
                    .filter(|l| l.contains(" WARN ") || l.contains(" ERROR "))
                    .map(|l| format!("[{name}] {}", l.trim())),
            );
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;
    use std::io::Write;

    #[test]
    fn only_new_whole_warning_and_error_lines_are_relayed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ingest-0.log");
        std::fs::write(&path, "2026 WARN old run's warning\n").unwrap();
        let mut relay = LogRelay::default();
        relay.follow(&path);
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        write!(
            f,
            "2026  INFO started\n2026  WARN frame 18: unreadable\n2026 ERROR half"
        )
        .unwrap();
        assert_eq!(
            relay.new_lines(),
            vec!["[ingest-0] 2026  WARN frame 18: unreadable".to_string()]
        );
        writeln!(f, " a line").unwrap();
        relay.follow(&path); // a restarted stage: the place is kept
        assert_eq!(
            relay.new_lines(),
            vec!["[ingest-0] 2026 ERROR half a line".to_string()]
        );
        assert!(relay.new_lines().is_empty());
    }
}
