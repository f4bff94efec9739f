//! Features: XFeat keypoints and descriptors of every frame (worker `k` of `N` takes the
//! frames with `seq % N == k`), written in place into the `features` service.

use crate::common::{send_features, send_slice, stamp, StageArgs, StageContext};
use crate::inbox::Inbox;
use anyhow::Result;
use supermvo_config::{Frontend, NetworkPlacement, PipelineConfig, Undistort};
use supermvo_dataset::{Camera, GrayImage, Sequence};
use supermvo_inference::aliked::{Aliked, AlikedConfig};
use supermvo_inference::models;
use supermvo_inference::orb::{Orb, OrbConfig};
use supermvo_inference::superpoint::{SuperPoint, SuperPointConfig};
use supermvo_inference::xfeat::{XFeat, XFeatConfig};
use supermvo_inference::{Extractor, Features, InferenceError};
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{now_ns, MessageError, StageKind, Status, Topic};

/// The extractor the daemon and `supermvo run --mode inprocess` both use.
pub fn extractor(
    cfg: &PipelineConfig,
    placement: NetworkPlacement,
) -> Result<Box<dyn Extractor + Send>> {
    Ok(match cfg.frontend {
        Frontend::XfeatLighterglue => Box::new(XFeat::new(
            &models::model_path("xfeat"),
            XFeatConfig {
                top_k: cfg.top_k,
                threads: cfg.extractor_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                subpixel: cfg.subpixel_keypoints,
                image_scale: cfg.image_scale as f32,
                ..Default::default()
            },
        )?),
        Frontend::SuperpointSuperglue => Box::new(SuperPoint::new(
            &models::model_path("superpoint"),
            SuperPointConfig {
                top_k: cfg.top_k,
                threads: cfg.extractor_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                ..Default::default()
            },
        )?),
        Frontend::AlikedLightglue => Box::new(Aliked::new(
            &models::model_path("aliked"),
            AlikedConfig {
                top_k: cfg.top_k,
                threads: cfg.extractor_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                ..Default::default()
            },
        )?),
        Frontend::Orb => Box::new(Orb::new(OrbConfig {
            top_k: cfg.top_k,
            ..Default::default()
        })),
    })
}

/// An extractor whose keypoints, found on frames as a camera with lens distortion recorded
/// them, are moved to where the pinhole camera of the same intrinsics sees them
/// ([`Camera::undistort_pixel`]); keypoints the lens model cannot invert are dropped.
pub struct UndistortedKeypoints<E> {
    inner: E,
    lens: Camera,
}

impl<E> std::fmt::Debug for UndistortedKeypoints<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "UndistortedKeypoints({:?})", self.lens)
    }
}

impl<E: Extractor> Extractor for UndistortedKeypoints<E> {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        let mut f = self.inner.extract(image)?;
        let lens = &self.lens;
        f.map_keypoints(|x, y| {
            lens.undistort_pixel(f64::from(x), f64::from(y))
                .map(|(u, v)| [u as f32, v as f32])
        });
        Ok(f)
    }
}

/// Sets `seq` up for the configured `undistort` and says whether keypoints must be
/// undistorted: for a camera with lens distortion and `undistort = "keypoints"`, frames load
/// as recorded and the lens is returned (wrap the extractor with [`with_lens`]); with
/// `"images"` frames are remapped as they load; a pinhole camera needs neither.
pub fn keypoint_lens(cfg: &PipelineConfig, seq: &mut Sequence) -> Option<Camera> {
    let lens = seq.lens().copied()?;
    let keypoints = cfg.undistort == Undistort::Keypoints;
    seq.set_remap_frames(!keypoints);
    keypoints.then_some(lens)
}

/// `extractor`, its keypoints undistorted with `lens` when there is one.
pub fn with_lens(
    extractor: Box<dyn Extractor + Send>,
    lens: Option<Camera>,
) -> Box<dyn Extractor + Send> {
    match lens {
        Some(lens) => Box::new(UndistortedKeypoints {
            inner: extractor,
            lens,
        }),
        None => extractor,
    }
}

/// Runs the network once on the sequence's first frame before the stage reports itself up:
/// ONNX Runtime sizes its buffers on the first call, which takes several times as long as
/// the next ones, and in real time the first frames would be late or dropped. Failures are
/// left to the frame itself to report.
fn warm_up(extractor: &mut dyn Extractor, seq: &Sequence) {
    if let Ok(image) = seq.load_frame(0) {
        let _ = extractor.extract(&image);
    }
}

/// Runs one features worker until SIGTERM.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let workers = cfg.features_workers as u64;
    let mut seq = Sequence::open_with_camera(&args.seq, cfg.camera.as_deref())?;
    let extractor = extractor(&cfg, NetworkPlacement::SideBySide)?;
    let mut extractor = with_lens(extractor, keypoint_lens(&cfg, &mut seq));
    let mut ctx = StageContext::new(StageKind::Features, args.worker, &cfg)?;
    let frames = ctx.slice_subscriber::<u8>(Topic::Frames)?;
    let publisher = ctx
        .services
        .slice_topic::<f32>(&ctx.node, Topic::Features, false)?
        .publisher_builder()
        .initial_max_slice_len(cfg.top_k * (3 + cfg.frontend.descriptor_dim()))
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .max_loaned_samples(2)
        .create()
        .map_err(|e| MessageError::ipc("features publisher", e))?;
    warm_up(extractor.as_mut(), &seq);
    ctx.started();
    // frames arrive in order from one ingest; the inbox only filters this worker's share and
    // the history a restart replays
    let mut inbox: Option<Inbox<Option<GrayImage>>> = None;
    while ctx.wait() {
        while let Some(s) = frames
            .receive()
            .map_err(|e| MessageError::ipc("frames", e))?
        {
            let h = *s.user_header();
            h.check()?;
            let image = (h.status() == Status::Ok).then(|| GrayImage {
                width: h.width as usize,
                height: h.height as usize,
                data: s.payload().to_vec(),
            });
            // the first frame seen fixes where this worker starts (after a restart, the
            // oldest frame in the history)
            let b = inbox.get_or_insert_with(|| {
                let first = h.seq + (args.worker as u64 + workers - h.seq % workers) % workers;
                Inbox::new(first, workers)
            });
            b.insert(h, image, now_ns());
        }
        let Some(b) = inbox.as_mut() else {
            ctx.heartbeat_if_idle();
            continue;
        };
        let _ = publisher.update_connections();
        while let Some((h_in, image, _received)) = b.pop() {
            let t_in = now_ns();
            let status = match (&image, h_in.status()) {
                (Some(img), Status::Ok) => {
                    let f = extractor.extract(img)?;
                    if cfg.features_extra_latency_ms > 0 {
                        std::thread::sleep(std::time::Duration::from_millis(
                            cfg.features_extra_latency_ms,
                        ));
                    }
                    let mut h = h_in.forward(Status::Ok);
                    stamp(&mut h, StageKind::Features);
                    let h = send_features(&publisher, h, &f)?;
                    ctx.frame_done(&h, t_in, b.len());
                    continue;
                }
                (_, st) => st,
            };
            let mut h = h_in.forward(status);
            stamp(&mut h, StageKind::Features);
            send_slice(&publisher, h, &[])?;
            ctx.frame_done(&h, t_in, b.len());
            if status == Status::EndOfStream {
                ctx.finished();
            }
        }
        ctx.heartbeat_if_idle();
    }
    Ok(())
}
