//! The stages' side of the diagnostic views: ingest publishes each camera image on
//! `view_images`, tracking each frame's [`FrameView`] and result on `view`. Both services drop
//! their oldest samples when a viewer falls behind, and a stage publishes only while a viewer
//! is attached, so a view never slows the pipeline and costs nothing when nobody looks. A
//! failure to publish a view is logged, never fatal.

use crate::common::StageContext;
use supermvo_features::FrameView;
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    FrameHeader, Ipc, MessageError, PubSubView, Topic, ViewHeader, ViewLayout,
};

type ImageService =
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        [u8],
        FrameHeader,
    >;

/// Whether a service has subscribers (a viewer attached).
fn listening<P: std::fmt::Debug + ?Sized + IceoryxSend, H: std::fmt::Debug + ZeroCopySend>(
    s: &supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        P,
        H,
    >,
) -> bool {
    s.dynamic_config().number_of_subscribers() > 0
}

/// Ingest's publisher of camera images for viewers.
pub struct ImageViews {
    service: ImageService,
    publisher: Publisher<Ipc, [u8], FrameHeader>,
}

impl std::fmt::Debug for ImageViews {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ImageViews")
    }
}

impl ImageViews {
    /// Opens the `view_images` service of the stage's pipeline for images of `len` bytes.
    pub fn open(ctx: &StageContext, len: usize) -> Result<Self, MessageError> {
        let service = ctx
            .services
            .slice_topic::<u8>(&ctx.node, Topic::ViewImages, false)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("view_images publisher", e))?;
        Ok(Self { service, publisher })
    }

    /// Whether a viewer listens.
    pub fn listening(&self) -> bool {
        listening(&self.service)
    }

    /// Publishes the image of frame `h` when a viewer listens.
    pub fn publish(&self, h: FrameHeader, pixels: &[u8]) {
        if !listening(&self.service) {
            return;
        }
        let sent = self
            .publisher
            .loan_slice_uninit(pixels.len())
            .map_err(|e| format!("{e:?}"))
            .and_then(|s| {
                let mut s = s.write_from_slice(pixels);
                *s.user_header_mut() = h;
                s.send().map_err(|e| format!("{e:?}"))
            });
        if let Err(e) = sent {
            tracing::debug!(seq = h.seq, "image view not published: {e}");
        }
    }
}

/// Tracking's publisher of frame views for viewers.
pub struct FrameViews {
    service: PubSubView,
    publisher: Publisher<Ipc, [f32], ViewHeader>,
}

impl std::fmt::Debug for FrameViews {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FrameViews")
    }
}

impl FrameViews {
    /// Opens the `view` service of the stage's pipeline.
    pub fn open(ctx: &StageContext, keypoints: usize) -> Result<Self, MessageError> {
        let service = ctx.services.view_topic(&ctx.node, false)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(8 * keypoints)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("view publisher", e))?;
        Ok(Self { service, publisher })
    }

    /// Whether a viewer listens (build the view only then).
    pub fn listening(&self) -> bool {
        listening(&self.service)
    }

    /// Publishes a frame's view and result.
    pub fn publish(&self, mut h: ViewHeader, view: &FrameView) {
        let sent = self
            .publisher
            .loan_slice_uninit(ViewLayout::len(view))
            .map_err(|e| format!("{e:?}"))
            .and_then(|s| {
                let mut s = s.write_from_fn(|_| 0.0);
                ViewLayout::write(view, &mut h, s.payload_mut());
                *s.user_header_mut() = h;
                s.send().map_err(|e| format!("{e:?}"))
            });
        if let Err(e) = sent {
            tracing::debug!(seq = h.frame.seq, "frame view not published: {e}");
        }
    }
}
