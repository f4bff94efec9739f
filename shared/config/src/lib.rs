//! SuPerMVO configuration.
//!
//! One serde struct per concern, `deny_unknown_fields` everywhere so a misspelt key is an
//! error rather than a silently ignored default, defaults for every option, and
//! [`Config::validate`] naming the offending key and its allowed range.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use supermvo_eval::{DeltaUnit, EvalOptions};

/// A configuration problem: file, key and what is allowed.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// Config file.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax error, unknown key or wrong type (the message names key and line).
    #[error("{path}: {message}")]
    Parse {
        /// Config file.
        path: PathBuf,
        /// Parser message.
        message: String,
    },
    /// A value outside its allowed range.
    #[error("config key '{key}' = {value}: {allowed}")]
    OutOfRange {
        /// Dotted key.
        key: String,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: String,
    },
}

/// Top-level configuration (`config/default.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Trajectory evaluation defaults.
    pub eval: EvalConfig,
    /// The VO pipeline and its daemon.
    pub pipeline: PipelineConfig,
}

/// How ingest feeds frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IngestMode {
    /// As fast as the pipeline accepts, never dropping a frame (back-pressure).
    Lossless,
    /// At the dataset's frame rate; frames the pipeline cannot take are dropped and reported.
    Realtime,
}

/// Where the learned front end's networks run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Device {
    /// ONNX Runtime's CPU execution provider.
    #[default]
    Cpu,
    /// ONNX Runtime's CUDA execution provider (`supermvo models fetch onnxruntime-gpu`, an
    /// NVIDIA GPU, CUDA 13 and cuDNN 9); the CPU, with a warning, where it cannot be used.
    Cuda,
}

/// How frames of a camera with lens distortion reach the pinhole model the tracker uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Undistort {
    /// Keypoints are found on the frames as recorded and then moved to where the pinhole
    /// camera sees them (as ORB-SLAM3 and stella_vslam do): nothing is resampled, and the
    /// whole field of view is kept.
    #[default]
    Keypoints,
    /// Each frame is remapped to the pinhole camera before the keypoints are found (a
    /// second resampling of the image; the edges lose detail).
    Images,
}

/// Keypoint extractor and matcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Frontend {
    /// XFeat keypoints, LighterGlue matching (ONNX Runtime).
    #[serde(rename = "xfeat-lighterglue")]
    XfeatLighterglue,
    /// ORB keypoints, brute-force Hamming matching.
    #[serde(rename = "orb")]
    Orb,
    /// SuperPoint keypoints, SuperGlue matching (the seed paper's pair; needs the official
    /// weights, exported with `supermvo models fetch superpoint|superglue --weights PATH`).
    #[serde(rename = "superpoint-superglue")]
    SuperpointSuperglue,
    /// ALIKED keypoints, LightGlue matching (the accuracy option; slower on a CPU).
    #[serde(rename = "aliked-lightglue")]
    AlikedLightglue,
}

impl Frontend {
    /// Length of one descriptor in floats (ORB's 256 bits travel as 8 bit-cast words).
    pub fn descriptor_dim(self) -> usize {
        match self {
            Self::XfeatLighterglue => 64,
            Self::Orb => 8,
            Self::SuperpointSuperglue => 256,
            Self::AlikedLightglue => 128,
        }
    }
}

impl std::str::FromStr for Frontend {
    type Err = String;

    /// The front end of a name as the configuration spells it.
    fn from_str(name: &str) -> Result<Self, String> {
        match name {
            "xfeat-lighterglue" => Ok(Self::XfeatLighterglue),
            "orb" => Ok(Self::Orb),
            "superpoint-superglue" => Ok(Self::SuperpointSuperglue),
            "aliked-lightglue" => Ok(Self::AlikedLightglue),
            other => Err(format!(
                "front end '{other}' is not available; use xfeat-lighterglue, aliked-lightglue, orb or superpoint-superglue"
            )),
        }
    }
}

/// Most frames seen while initialising that the tracker poses later
/// (`pipeline.backfill_frames`): what one pose message between the daemon's processes carries.
pub const MAX_BACKFILL_FRAMES: usize = 16;

/// The factors `pipeline.image_scale` allows (XFeat on a reduced frame).
pub const IMAGE_SCALE_RANGE: std::ops::RangeInclusive<f64> = 0.25..=1.0;

/// `[pipeline]`: the VO pipeline, in process or as the multi-process daemon.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    /// Name of the daemon's pipeline: its shared-memory services are named after it, and only
    /// one pipeline of a name runs at a time. Letters, digits, '-' and '_'.
    pub name: String,
    /// "lossless" or "realtime".
    pub mode: IngestMode,
    /// Real-time replay speed factor: 1.0 replays at the dataset's own rate (10 Hz for KITTI,
    /// from times.txt), 2.0 twice as fast. (0, 100].
    pub speed: f64,
    /// Front end: "xfeat-lighterglue" (learned, the default), "aliked-lightglue" (learned,
    /// more accurate, slower), "superpoint-superglue" (official weights needed) or "orb" (the
    /// classical baseline: ORB keypoints, brute-force Hamming matching).
    pub frontend: Frontend,
    /// Keypoints per frame, [64, 8192].
    pub top_k: usize,
    /// Keypoints the matcher and loop closing are given: the strongest of each frame's
    /// `top_k`, [0, 8192]; 0 (or `top_k` and over): all of them. Below `top_k` the tracker
    /// still finds its landmarks among all `top_k` by projection, at the matcher's cost
    /// of this many (docs/vo.md, "More keypoints than the matcher sees").
    pub matcher_top_k: usize,
    /// ONNX Runtime intra-op threads per network, [1, 64].
    pub threads: usize,
    /// Intra-op threads of the feature extractor alone, [0, 64]; 0: automatic (`threads`
    /// in one process; half of them in the daemon, where extraction of the next frame runs
    /// beside matching of this one).
    pub features_threads: usize,
    /// Intra-op threads of the matcher alone, [0, 64]; 0: automatic, as `features_threads`.
    pub matching_threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls. Off: extraction and
    /// matching alternate on the same cores, and a spinning idle session takes them from the
    /// running one (`tools/bench_spinning.py`).
    pub thread_spinning: bool,
    /// Where the networks run: "cpu" or "cuda".
    pub device: Device,
    /// Feature-extraction worker processes taking alternate frames, [1, 8].
    pub features_workers: usize,
    /// Keyframes in the local bundle-adjustment window (0 disables it), [0, 30].
    pub ba_window: usize,
    /// The window chosen by covisibility: the new keyframe and the keyframes sharing at
    /// least this many landmarks with it, the most shared first, up to `ba_window` in all;
    /// 0 (the default): the last `ba_window` keyframes, [0, 1000].
    pub ba_min_shared: usize,
    /// New keyframe when fewer landmarks are tracked than this fraction of the reference
    /// keyframe's (ORB-SLAM's rule); 0 (the default) leaves only the fixed count and the
    /// frame limit, [0, 1].
    pub keyframe_ratio: f64,
    /// After a frame fails to track, the map is kept and the next frames are tracked
    /// against it (at its own scale) for at most this many frames in a row before a new map
    /// is started; 0 starts one at once, [0, 100].
    pub relocalisation_frames: usize,
    /// A frame whose keyframe matches agree with fewer landmarks than tracking needs within
    /// the PnP gate (2 px) is tracked with the gate widened by this factor when more agree
    /// there; 1 switches it off (the tracker before 2026-12-02), [1, 3].
    pub pnp_gate_widening: f64,
    /// Frames seen while the tracker initialises (before the first map, or a new one after
    /// a loss) are posed once the map exists, on its landmarks: the most recent this many;
    /// 0 leaves them unposed, [0, 16] (what one pose message carries).
    pub backfill_frames: usize,
    /// A frame whose matches reach the reference keyframe but not its map (tracking fails)
    /// starts a new map from that keyframe, whose pose is known, as its second view; false:
    /// the frame itself starts the new map, placed at the last tracked pose.
    pub reinitialise_on_reference: bool,
    /// That new map takes the old map's scale from the depths of the landmarks the keyframe
    /// saw (the median ratio over 10 or more keypoints it shares with the new map); false, or
    /// with fewer: the new map's median depth is set to the first map's.
    pub reinitialise_at_map_scale: bool,
    /// New landmarks also between each new keyframe and this many keyframes before its
    /// reference: keypoints the matcher left free, paired along the epipolar line by
    /// descriptor and triangulated with the usual checks; 0 switches it off, [0, 4].
    pub covisible_triangulation: usize,
    /// The frame's final robust pose refinement gives no weight to a landmark match whose
    /// error exceeds this many times the PnP gate (2 px), [1, 10].
    pub robust_cutoff: f64,
    /// After every local BA, read the radial coefficient its observations ask for beyond
    /// the calibration, and report the run's information-weighted mean (`supermvo run`: a
    /// summary line and `lens_residual` in report.json; in the daemon only where the local
    /// BA is solved at once, lossless). A diagnostic of the lens model; it changes no pose.
    pub lens_check: bool,
    /// Learn the radial coefficient k1 the calibration misses from the local BAs of windows
    /// that turn, and see every observation through it from then on (in process and the
    /// lossless daemon; in real time the daemon hands its local BAs over and learns nothing).
    /// On by default: it starts only once the turning windows read at least `lens_min_k1`.
    pub lens_self_calibration: bool,
    /// The smallest radial error `lens_self_calibration` corrects: it learns only once the
    /// turning windows' readings average at least this far from the calibration, [0, 0.05].
    pub lens_min_k1: f64,
    /// Camera file (ORB-SLAM3 / OpenCV YAML or EuRoC `sensor.yaml`) with the intrinsics and
    /// lens distortion of the frames; replaces KITTI's `calib.txt` and EuRoC's own
    /// `sensor.yaml`, and is needed by TUM and image-folder sequences without `camera.yaml`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<std::path::PathBuf>,
    /// With lens distortion: "keypoints" (undistorted after extraction, the default) or
    /// "images" (frames remapped before it).
    pub undistort: Undistort,
    /// Run the matcher on every frame against the reference keyframe (the default). false:
    /// only for initialisation, new keyframes and frames that projection does not track;
    /// the other frames are tracked by projecting the map (1.7-2x faster on the full-rate
    /// clips, but less accurate on some sub-sampled ones; docs/decisions).
    pub match_every_frame: bool,
    /// Restarts allowed per stage before the supervisor gives up, [0, 100].
    pub max_restarts: u32,
    /// First restart delay in milliseconds, doubled on each further restart of a stage, [0, 10000].
    pub restart_backoff_ms: u64,
    /// A stage that reports nothing for this long is considered hung and restarted, in
    /// milliseconds, [1000, 600000].
    pub deadline_ms: u64,
    /// How long a stage waits for a missing frame before reporting it lost, milliseconds,
    /// [500, 600000].
    pub gap_timeout_ms: u64,
    /// Process at most this many frames (0: all).
    pub max_frames: usize,
    /// Replay the sequence this many times (soak tests), [1, 100000].
    pub loops: usize,
    /// Extra wait per frame in each features worker, ms, [0, 10000]: emulates a front end
    /// that waits on an accelerator (for scaling tests); 0 in normal use.
    pub features_extra_latency_ms: u64,
    /// Recognise revisited places and correct the trajectory (and the tracker's map) with a
    /// Sim(3) pose graph of keyframes.
    pub loop_closure: bool,
    /// Run the tracker's local mapping in the daemon's back-end process: each keyframe's
    /// triangulations and local bundle adjustment (lossless: the tracker waits for each, the
    /// run stays bit-identical; real time: the tracker triangulates itself, goes on and
    /// applies the BA solution when it arrives). false keeps them in the tracking process.
    /// In one process they always run in the tracker.
    pub local_ba_in_backend: bool,
    /// LighterGlue point pruning (LightGlue's `width_confidence`): points the network rates
    /// unmatchable leave after each layer. In (0, 1), or -1 to run every point through every
    /// layer.
    pub width_confidence: f64,
    /// LighterGlue early stopping (LightGlue's `depth_confidence`): the remaining layers are
    /// skipped once this fraction of the points is confident. In (0, 1), or -1 to run every
    /// layer.
    pub depth_confidence: f64,
    /// XFeat keypoints at sub-pixel precision (a Gaussian fitted to the detection heatmap
    /// around each maximum); false (the default) keeps the reference's integer pixel
    /// positions.
    pub subpixel_keypoints: bool,
    /// XFeat runs on the frame resized by this factor, [0.25, 1]; keypoints stay in the
    /// frame's pixels (the network's sides cut down to multiples of 32). 0.75 tracks the
    /// KITTI clips more accurately than the full frame but a radial-tangential lens and two
    /// rendered streets worse (docs/decisions/2026-12-02-xfeat-at-three-quarters-of-the-frame.md,
    /// docs/decisions/2026-12-06-xfeat-at-three-quarters-nearest-rounding.md), so 1 (the
    /// full frame) stays the default; the real-time profile uses 0.75 for its cost. Other
    /// front ends see the full frame.
    pub image_scale: f64,
    /// Seed of the tracker's random sampling (the essential-matrix and PnP RANSAC): 0 (the
    /// default) gives the reported runs; any other value a different, equally deterministic
    /// run, to see how much a result depends on which samples RANSAC happened to draw.
    pub seed: u64,
}

/// How the extractor and the matcher share the machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NetworkPlacement {
    /// One after the other in one process (`supermvo run --mode inprocess`).
    Alternating,
    /// At the same time, in the daemon's features and matching processes.
    SideBySide,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            name: "supermvo".into(),
            mode: IngestMode::Lossless,
            frontend: Frontend::XfeatLighterglue,
            speed: 1.0,
            top_k: 1024,
            matcher_top_k: 0,
            threads: 2,
            features_threads: 0,
            matching_threads: 0,
            thread_spinning: false,
            device: Device::Cpu,
            features_workers: 1,
            ba_window: 6,
            ba_min_shared: 0,
            keyframe_ratio: 0.0,
            relocalisation_frames: 5,
            pnp_gate_widening: 1.5,
            backfill_frames: 16,
            reinitialise_on_reference: true,
            reinitialise_at_map_scale: true,
            covisible_triangulation: 0,
            robust_cutoff: 3.0,
            lens_check: false,
            lens_self_calibration: true,
            lens_min_k1: 0.005,
            camera: None,
            undistort: Undistort::Keypoints,
            match_every_frame: true,
            max_restarts: 5,
            restart_backoff_ms: 100,
            deadline_ms: 20_000,
            gap_timeout_ms: 10_000,
            max_frames: 0,
            loops: 1,
            features_extra_latency_ms: 0,
            loop_closure: true,
            local_ba_in_backend: true,
            width_confidence: 0.95,
            depth_confidence: -1.0,
            subpixel_keypoints: false,
            image_scale: 1.0,
            seed: 0,
        }
    }
}

impl PipelineConfig {
    /// Keypoints the matcher and loop closing are given (see `matcher_top_k`): `None` when
    /// that is every keypoint of the frame.
    pub fn matcher_keypoints(&self) -> Option<usize> {
        (self.matcher_top_k > 0 && self.matcher_top_k < self.top_k).then_some(self.matcher_top_k)
    }

    /// Intra-op threads of the feature extractor placed as given.
    pub fn extractor_threads(&self, placement: NetworkPlacement) -> usize {
        self.stage_threads(self.features_threads, placement)
    }

    /// Intra-op threads of the matcher placed as given.
    pub fn matcher_threads(&self, placement: NetworkPlacement) -> usize {
        self.stage_threads(self.matching_threads, placement)
    }

    /// A stage's own setting, or by default `threads` for networks that take turns and
    /// half of them (at least one) for networks that run at the same time.
    fn stage_threads(&self, own: usize, placement: NetworkPlacement) -> usize {
        match (own, placement) {
            (0, NetworkPlacement::Alternating) => self.threads,
            (0, NetworkPlacement::SideBySide) => (self.threads / 2).max(1),
            (n, _) => n,
        }
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        fn range<T: PartialOrd + ToString>(
            key: &str,
            v: T,
            lo: T,
            hi: T,
        ) -> Result<(), ConfigError> {
            if v >= lo && v <= hi {
                Ok(())
            } else {
                Err(ConfigError::OutOfRange {
                    key: format!("pipeline.{key}"),
                    value: v.to_string(),
                    allowed: format!("must be in [{}, {}]", lo.to_string(), hi.to_string()),
                })
            }
        }
        if self.name.is_empty()
            || self.name.len() > 64
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(ConfigError::OutOfRange {
                key: "pipeline.name".into(),
                value: format!("{:?}", self.name),
                allowed: "must be 1 to 64 letters, digits, '-' or '_'".into(),
            });
        }
        if !(self.speed > 0.0 && self.speed <= 100.0) {
            return Err(ConfigError::OutOfRange {
                key: "pipeline.speed".into(),
                value: self.speed.to_string(),
                allowed: "must be in (0, 100]".into(),
            });
        }
        for (key, v) in [
            ("width_confidence", self.width_confidence),
            ("depth_confidence", self.depth_confidence),
        ] {
            if !(v == -1.0 || (v > 0.0 && v < 1.0)) {
                return Err(ConfigError::OutOfRange {
                    key: format!("pipeline.{key}"),
                    value: v.to_string(),
                    allowed: "must be in (0, 1), or -1 to switch it off".into(),
                });
            }
        }
        if !(0.0..=1.0).contains(&self.keyframe_ratio) {
            return Err(ConfigError::OutOfRange {
                key: "pipeline.keyframe_ratio".into(),
                value: self.keyframe_ratio.to_string(),
                allowed: "must be in [0, 1]".into(),
            });
        }
        if !IMAGE_SCALE_RANGE.contains(&self.image_scale) {
            return Err(ConfigError::OutOfRange {
                key: "pipeline.image_scale".into(),
                value: self.image_scale.to_string(),
                allowed: "must be in [0.25, 1]".into(),
            });
        }
        if !(1.0..=3.0).contains(&self.pnp_gate_widening) {
            return Err(ConfigError::OutOfRange {
                key: "pipeline.pnp_gate_widening".into(),
                value: self.pnp_gate_widening.to_string(),
                allowed: "must be in [1, 3]".into(),
            });
        }
        range("top_k", self.top_k, 64, 8192)?;
        range("matcher_top_k", self.matcher_top_k, 0, 8192)?;
        range("threads", self.threads, 1, 64)?;
        range("features_threads", self.features_threads, 0, 64)?;
        range("matching_threads", self.matching_threads, 0, 64)?;
        range("features_workers", self.features_workers, 1, 8)?;
        range("ba_window", self.ba_window, 0, 30)?;
        range("ba_min_shared", self.ba_min_shared, 0, 1000)?;
        range(
            "covisible_triangulation",
            self.covisible_triangulation,
            0,
            4,
        )?;
        range("robust_cutoff", self.robust_cutoff, 1.0, 10.0)?;
        range("lens_min_k1", self.lens_min_k1, 0.0, 0.05)?;
        range("relocalisation_frames", self.relocalisation_frames, 0, 100)?;
        range(
            "backfill_frames",
            self.backfill_frames,
            0,
            MAX_BACKFILL_FRAMES,
        )?;
        range("max_restarts", self.max_restarts, 0, 100)?;
        range("restart_backoff_ms", self.restart_backoff_ms, 0, 10_000)?;
        range("deadline_ms", self.deadline_ms, 1000, 600_000)?;
        range("gap_timeout_ms", self.gap_timeout_ms, 500, 600_000)?;
        range("loops", self.loops, 1, 100_000)?;
        range(
            "features_extra_latency_ms",
            self.features_extra_latency_ms,
            0,
            10_000,
        )?;
        Ok(())
    }
}

/// `[eval]`: defaults of `supermvo eval`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Alignment: "none", "se3", "sim3" or "scale".
    pub align: supermvo_geometry::AlignmentKind,
    /// RPE step (positive; an integer when `delta_unit = "frames"`).
    pub delta: f64,
    /// RPE step unit: "frames" or "meters".
    pub delta_unit: DeltaUnit,
    /// Association tolerance in seconds, (0, 10].
    pub t_max_diff: f64,
    /// Choose RPE pairs along the reference instead of the estimate.
    pub pairs_from_reference: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        let o = EvalOptions::default();
        Self {
            align: o.align,
            delta: o.delta,
            delta_unit: o.delta_unit,
            t_max_diff: o.t_max_diff,
            pairs_from_reference: o.pairs_from_reference,
        }
    }
}

impl EvalConfig {
    /// The evaluation options these settings describe.
    pub fn options(&self) -> EvalOptions {
        EvalOptions {
            align: self.align,
            delta: self.delta,
            delta_unit: self.delta_unit,
            t_max_diff: self.t_max_diff,
            pairs_from_reference: self.pairs_from_reference,
        }
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |key: &str, value: String, allowed: &str| {
            Err(ConfigError::OutOfRange {
                key: key.into(),
                value,
                allowed: allowed.into(),
            })
        };
        if !(self.delta.is_finite() && self.delta > 0.0) {
            return bad("eval.delta", self.delta.to_string(), "must be positive");
        }
        if self.delta_unit == DeltaUnit::Frames && self.delta.fract() != 0.0 {
            return bad(
                "eval.delta",
                self.delta.to_string(),
                "must be a whole number of frames when eval.delta_unit = \"frames\"",
            );
        }
        if !(self.t_max_diff > 0.0 && self.t_max_diff <= 10.0) {
            return bad(
                "eval.t_max_diff",
                self.t_max_diff.to_string(),
                "must be in (0, 10] seconds",
            );
        }
        Ok(())
    }
}

impl Config {
    /// Parses TOML text; `origin` names the source in errors.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let cfg: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: origin.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The built-in profiles (`supermvo run --profile NAME`), each a file of `config/`.
    pub const PROFILES: [(&'static str, &'static str); 1] =
        [("realtime", include_str!("../../../config/realtime.toml"))];

    /// A built-in profile by name; the error lists the names there are.
    pub fn profile(name: &str) -> Result<Self, ConfigError> {
        match Self::PROFILES.iter().find(|(n, _)| *n == name) {
            Some((n, text)) => Self::from_toml(text, Path::new(&format!("config/{n}.toml"))),
            None => Err(ConfigError::OutOfRange {
                key: "--profile".into(),
                value: name.into(),
                allowed: format!(
                    "must be one of: {}",
                    Self::PROFILES.map(|(n, _)| n).join(", ")
                ),
            }),
        }
    }

    /// Reads and validates a TOML file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Self::from_toml(&text, path)
    }

    /// Validates every section.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.eval.validate()?;
        self.pipeline.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn networks_side_by_side_share_the_threads_unless_set() {
        let mut p = PipelineConfig::default();
        let (one, both) = (NetworkPlacement::Alternating, NetworkPlacement::SideBySide);
        assert_eq!((p.extractor_threads(one), p.matcher_threads(one)), (2, 2));
        assert_eq!((p.extractor_threads(both), p.matcher_threads(both)), (1, 1));
        p.threads = 1;
        assert_eq!(p.matcher_threads(both), 1);
        p.threads = 8;
        p.matching_threads = 6;
        assert_eq!((p.extractor_threads(both), p.matcher_threads(both)), (4, 6));
        assert_eq!(p.matcher_threads(one), 6);
        p.features_threads = 65;
        assert!(p.validate().is_err());
    }

    #[test]
    fn the_matcher_sees_every_keypoint_unless_fewer_are_set() {
        let mut p = PipelineConfig::default();
        assert_eq!(p.matcher_keypoints(), None);
        p.matcher_top_k = 1024;
        assert_eq!(p.matcher_keypoints(), None, "as many as top_k: all of them");
        p.top_k = 2048;
        assert_eq!(p.matcher_keypoints(), Some(1024));
        p.matcher_top_k = 4096;
        assert_eq!(p.matcher_keypoints(), None);
        let err = Config::from_toml("[pipeline]\nmatcher_top_k = 9000\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("pipeline.matcher_top_k"), "{err}");
    }

    #[test]
    fn unknown_key_is_named() {
        let err = Config::from_toml("[eval]\nallign = \"sim3\"\n", Path::new("my.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("my.toml") && err.contains("allign") && err.contains("line 2"),
            "{err}"
        );
    }

    #[test]
    fn out_of_range_names_key() {
        let err = Config::from_toml("[eval]\nt_max_diff = -1.0\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("eval.t_max_diff"), "{err}");
        let err = Config::from_toml("[eval]\ndelta = 2.5\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("whole number"), "{err}");
        let err = Config::from_toml("[pipeline]\nfeatures_workers = 0\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("pipeline.features_workers") && err.contains("[1, 8]"),
            "{err}"
        );
        let err = Config::from_toml("[pipeline]\nname = \"a/b\"\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("pipeline.name"), "{err}");
        for (key, bad) in [
            ("depth_confidence", "1.5"),
            ("depth_confidence", "0.0"),
            ("depth_confidence", "-0.5"),
            ("keyframe_ratio", "1.5"),
            ("keyframe_ratio", "-0.1"),
            ("robust_cutoff", "0.5"),
            ("robust_cutoff", "11.0"),
            ("lens_min_k1", "-0.001"),
            ("covisible_triangulation", "5"),
            ("image_scale", "0.2"),
            ("image_scale", "1.5"),
        ] {
            let err =
                Config::from_toml(&format!("[pipeline]\n{key} = {bad}\n"), Path::new("c.toml"))
                    .unwrap_err()
                    .to_string();
            assert!(err.contains(&format!("pipeline.{key}")), "{err}");
        }
        let cfg = Config::from_toml("[pipeline]\nkeyframe_ratio = 0.9\n", Path::new("c.toml"));
        assert_eq!(cfg.unwrap().pipeline.keyframe_ratio, 0.9);
        let cfg = Config::from_toml(
            "[pipeline]\nwidth_confidence = -1\ndepth_confidence = 0.95\nsubpixel_keypoints = true\n",
            Path::new("c.toml"),
        )
        .unwrap();
        assert_eq!(cfg.pipeline.width_confidence, -1.0);
        assert_eq!(cfg.pipeline.depth_confidence, 0.95);
        assert!(cfg.pipeline.subpixel_keypoints);
        let cfg =
            Config::from_toml("[pipeline]\nimage_scale = 0.5\n", Path::new("c.toml")).unwrap();
        assert_eq!(cfg.pipeline.image_scale, 0.5);
        let cfg = Config::from_toml("[pipeline]\nseed = 7\n", Path::new("c.toml")).unwrap();
        assert_eq!(cfg.pipeline.seed, 7);
    }

    #[test]
    fn the_realtime_profile_is_the_default_with_a_smaller_front_end() {
        let cfg = Config::profile("realtime").unwrap();
        let p = &cfg.pipeline;
        assert_eq!(p.mode, IngestMode::Realtime);
        assert_eq!((p.top_k, p.threads, p.image_scale), (768, 1, 0.75));
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/realtime.toml");
        assert_eq!(Config::load(&path).unwrap(), cfg);
        let err = Config::profile("fast").unwrap_err().to_string();
        assert!(
            err.contains("--profile") && err.contains("realtime"),
            "{err}"
        );
    }

    #[test]
    fn shipped_default_config_parses_and_equals_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/default.toml");
        let cfg = Config::load(&path).unwrap();
        assert_eq!(cfg, Config::default());
    }
}
