//! Frames of a video file, decoded by the `ffmpeg` program (Debian's `ffmpeg` package;
//! `tools/setup.sh` installs it; `SUPERMVO_FFMPEG` names another binary). Opening a video lists
//! its packets without decoding them (ffmpeg's `framecrc` muxer on a stream copy: the frame
//! size, the time base and each frame's presentation time, sorted into presentation order), so
//! every process that opens it pays a file read, not a decode; frames are then decoded in
//! order, as grey (the luma plane), by one ffmpeg process streaming raw frames through a pipe.
//! Asking for an earlier frame starts it again. Every frame is kept (`-fps_mode passthrough`:
//! none duplicated or dropped to a rate).

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
        .args(["-map", "0:v:0"])
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
            &["-c", "copy", "-f", "framecrc", "-"],
            Stdio::piped(),
            Stdio::piped(),
        )?;
        let out = child
            .wait_with_output()
            .map_err(|e| DatasetError::invalid(path, format!("reading ffmpeg's output: {e}")))?;
        let log = String::from_utf8_lossy(&out.stderr);
        let (size, stamps) = parse_framecrc(&String::from_utf8_lossy(&out.stdout));
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

/// Frame size and presentation times (sorted) from ffmpeg's `framecrc` listing of a stream
/// copy: `#tb 0: NUM/DEN`, `#dimensions 0: WxH`, then a `stream, dts, pts, duration, size, crc`
/// line per packet, in decoding order.
fn parse_framecrc(listing: &str) -> (Option<(usize, usize)>, Vec<f64>) {
    let (mut size, mut tb) = (None, None);
    let mut pts = Vec::new();
    for line in listing.lines() {
        if let Some(v) = line.strip_prefix("#tb 0:") {
            tb = v.trim().split_once('/').and_then(|(n, d)| {
                Some((n.trim().parse::<f64>().ok()?, d.trim().parse::<f64>().ok()?))
            });
        } else if let Some(v) = line.strip_prefix("#dimensions 0:") {
            size = v
                .trim()
                .split_once('x')
                .and_then(|(w, h)| Some((w.trim().parse().ok()?, h.trim().parse().ok()?)));
        } else if !line.starts_with('#') {
            if let Some(p) = line
                .split(',')
                .nth(2)
                .and_then(|v| v.trim().parse::<i64>().ok())
            {
                pts.push(p);
            }
        }
    }
    pts.sort_unstable();
    let stamps = tb.map_or_else(Vec::new, |(num, den)| {
        pts.iter().map(|&p| p as f64 * num / den).collect()
    });
    (size, stamps)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_packet_listing_gives_size_and_times_in_presentation_order() {
        let listing = "#tb 0: 1/10240\n#media_type 0: video\n#dimensions 0: 1226x370\n\
            0,      -2048,          0,     1024,    83024, 0x625c030a\n\
            0,      -1024,       2048,     1024,    47993, 0x5c193f90, F=0x0\n\
            0,          0,       1024,     1024,    20341, 0x22d885bd, F=0x0\n";
        let (size, stamps) = parse_framecrc(listing);
        assert_eq!(size, Some((1226, 370)));
        assert_eq!(stamps, vec![0.0, 0.1, 0.2]);
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
