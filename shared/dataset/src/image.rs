//! 8-bit grayscale images.

use crate::DatasetError;
use std::path::Path;

/// A grayscale image, row-major, one byte per pixel.
#[derive(Clone, PartialEq, Eq)]
pub struct GrayImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` intensities, row by row.
    pub data: Vec<u8>,
}

impl std::fmt::Debug for GrayImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GrayImage({}x{})", self.width, self.height)
    }
}

impl GrayImage {
    /// Wraps pixel data; `None` unless `data.len() == width * height`.
    pub fn new(width: usize, height: usize, data: Vec<u8>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// Reads a PNG (any colour type is converted to 8-bit luma).
    pub fn load(path: &Path) -> Result<Self, DatasetError> {
        let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
        let img = image::load_from_memory(&bytes)
            .map_err(|e| DatasetError::invalid(path, format!("unreadable image: {e}")))?
            .into_luma8();
        let (w, h) = img.dimensions();
        if w == 0 || h == 0 {
            return Err(DatasetError::invalid(path, "image has zero size"));
        }
        Ok(Self {
            width: w as usize,
            height: h as usize,
            data: img.into_raw(),
        })
    }

    /// Pixel at `(x, y)`.
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }
}
