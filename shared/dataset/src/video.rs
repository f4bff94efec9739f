//! Frames of a video file, decoded by the `ffmpeg` program (Debian's `ffmpeg` package;
//! `tools/setup.sh` installs it; `SUPERMVO_FFMPEG` names another binary). Opening a video runs
//! one pass of ffmpeg's `showinfo` filter for the frame count, size and each frame's
//! presentation time; frames are then decoded in order, as grey (the luma plane), by one
//! ffmpeg process streaming raw frames through a pipe. Asking for an earlier frame starts it
//! again. Every frame is kept (`-fps_mode passthrough`: none duplicated or dropped to a rate).

use crate::{DatasetError, GrayImage};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::Mutex;

/// File extensions read as video.
pub const VIDEO_EXTENSIONS: [&str; 7] = ["mp4", "mkv", "avi", "mov", "webm", "m4v", "mpg"];

/// Whether `path` is a file with a video extension.
pub fn is_video(path: &Path) -> bool {
    path.is_file()
        && path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The ffmpeg binary.
fn ffmpeg() -> PathBuf {
    std::env::var_os("SUPERMVO_FFMPEG")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("ffmpeg"))
}

/// Starts ffmpeg on `path` with `args` after the input; a missing binary is a clear error.
fn spawn(path: &Path, args: &[&str], stdout: Stdio, stderr: Stdio) -> Result<Child, DatasetError> {
    spawn_with(&ffmpeg(), path, args, (stdout, stderr))
}

fn spawn_with(
    binary: &Path,
    path: &Path,
    args: &[&str],
    (stdout, stderr): (Stdio, Stdio),
) -> Result<Child, DatasetError> {
    Command::new(binary)
        .args(["-hide_banner", "-nostdin", "-i"])
        .arg(path)
        .args(["-map", "0:v:0", "-fps_mode", "passthrough"])
        .args(args)
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .map_err(|e| {
            DatasetError::invalid(
                path,
                format!(
                    "cannot run {} to decode the video ({e}); install FFmpeg (tools/setup.sh does: apt-get install ffmpeg) or set SUPERMVO_FFMPEG",
                    binary.display()
                ),
            )
        })
}

/// A video's frames (see the module docs).
#[derive(Debug)]
pub struct Video {
    path: PathBuf,
    /// Frame width and height, pixels.
    pub size: (usize, usize),
    /// Presentation time of each frame, seconds.
    pub stamps: Vec<f64>,
    decoder: Mutex<Option<Decoder>>,
}

#[derive(Debug)]
struct Decoder {
    child: Child,
    out: ChildStdout,
    next: usize,
}

impl Drop for Decoder {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Video {
    /// Probes `path`: frame count, size and times.
    pub fn open(path: &Path) -> Result<Self, DatasetError> {
        let child = spawn(
            path,
            &["-vf", "showinfo", "-f", "null", "-"],
            Stdio::null(),
            Stdio::piped(),
        )?;
        let out = child
            .wait_with_output()
            .map_err(|e| DatasetError::invalid(path, format!("reading ffmpeg's output: {e}")))?;
        let log = String::from_utf8_lossy(&out.stderr);
        let (size, stamps) = parse_showinfo(&log);
        if !out.status.success() || stamps.is_empty() {
            let why = log
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("no video frames");
            return Err(DatasetError::invalid(
                path,
                format!("not a readable video (ffmpeg: {why})"),
            ));
        }
        let size =
            size.ok_or_else(|| DatasetError::invalid(path, "ffmpeg reported no frame size"))?;
        Ok(Self {
            path: path.to_path_buf(),
            size,
            stamps,
            decoder: Mutex::new(None),
        })
    }

    /// Frame `i` (0-based), grey.
    pub fn frame(&self, i: usize) -> Result<GrayImage, DatasetError> {
        if i >= self.stamps.len() {
            return Err(DatasetError::invalid(&self.path, format!("no frame {i}")));
        }
        let mut slot = self
            .decoder
            .lock()
            .map_err(|_| DatasetError::invalid(&self.path, "video decoder poisoned"))?;
        if slot.as_ref().is_none_or(|d| d.next > i) {
            *slot = None; // stops the old process first
            let mut child = spawn(
                &self.path,
                &[
                    "-loglevel",
                    "error",
                    "-f",
                    "rawvideo",
                    "-pix_fmt",
                    "gray",
                    "pipe:1",
                ],
                Stdio::piped(),
                Stdio::null(),
            )?;
            let out = child
                .stdout
                .take()
                .ok_or_else(|| DatasetError::invalid(&self.path, "no pipe from ffmpeg"))?;
            *slot = Some(Decoder {
                child,
                out,
                next: 0,
            });
        }
        let (w, h) = self.size;
        let mut data = vec![0u8; w * h];
        if let Some(d) = slot.as_mut() {
            while d.next <= i {
                d.out.read_exact(&mut data).map_err(|e| {
                    DatasetError::invalid(
                        &self.path,
                        format!("frame {}: decoding failed ({e})", d.next),
                    )
                })?;
                d.next += 1;
            }
        }
        Ok(GrayImage {
            width: w,
            height: h,
            data,
        })
    }
}

/// Frame size and presentation times from ffmpeg's `showinfo` lines
/// (`... n:   0 pts:      0 pts_time:0  ... s:1226x370 ...`).
fn parse_showinfo(log: &str) -> (Option<(usize, usize)>, Vec<f64>) {
    let mut size = None;
    let mut stamps = Vec::new();
    for line in log
        .lines()
        .filter(|l| l.contains("Parsed_showinfo") && l.contains(" n:"))
    {
        let field = |key: &str| {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(key))
                .map(str::to_string)
        };
        let Some(t) = field("pts_time:").and_then(|v| v.parse::<f64>().ok()) else {
            continue;
        };
        stamps.push(t);
        if size.is_none() {
            size = field("s:").and_then(|s| {
                let (w, h) = s.split_once('x')?;
                Some((w.parse().ok()?, h.parse().ok()?))
            });
        }
    }
    (size, stamps)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn showinfo_lines_give_size_and_times() {
        let log = "[Parsed_showinfo_0 @ 0x1] config in time_base: 1/10240, frame_rate: 10/1\n\
            [Parsed_showinfo_0 @ 0x1] n:   0 pts:      0 pts_time:0       pos:       48 fmt:yuv420p sar:0/1 s:1226x370 i:P\n\
            [Parsed_showinfo_0 @ 0x1] n:   1 pts:   1024 pts_time:0.1     pos:    99 fmt:yuv420p sar:0/1 s:1226x370 i:P\n";
        let (size, stamps) = parse_showinfo(log);
        assert_eq!(size, Some((1226, 370)));
        assert_eq!(stamps, vec![0.0, 0.1]);
    }

    #[test]
    fn a_missing_ffmpeg_is_one_clear_error() {
        let err = spawn_with(
            Path::new("/nonexistent/ffmpeg"),
            Path::new("clip.mp4"),
            &[],
            (Stdio::null(), Stdio::null()),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("clip.mp4")
                && err.contains("/nonexistent/ffmpeg")
                && err.contains("apt-get install ffmpeg"),
            "{err}"
        );
    }
}
