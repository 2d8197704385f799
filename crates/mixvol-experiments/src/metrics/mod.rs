//! Image-quality metrics of the accuracy report, one per file. Every metric compares a rendered
//! frame with a reference frame of the same size, both premultiplied RGBA in [0, 1] as the
//! renderer returns them (row-major, top row first).
//!
//! - [`pixel`]: RMSE and PSNR of the pixels (what the report measured first);
//! - [`gradient`]: the RMS error of the image's finite differences, which a seam (a jump
//!   between neighbouring pixels that the reference does not have) raises far more than RMSE;
//! - [`ssim`]: the structural similarity index, from the `image-compare` crate;
//! - [`seam`]: the image jump across the projected brick faces where the resolution level
//!   changes, against the same jump in the reference.

pub mod gradient;
pub mod pixel;
pub mod seam;
pub mod ssim;

use glam::Vec4;
use thiserror::Error;

/// Why a metric could not be computed.
#[derive(Debug, Error)]
pub enum MetricError {
    /// The two images differ in size, or a buffer does not hold `width * height` pixels.
    #[error("image sizes differ: {width}x{height} wants {expected} pixels, got {got}")]
    SizeMismatch {
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// `width * height`.
        expected: usize,
        /// Pixels in the offending buffer.
        got: usize,
    },
    /// The level list does not hold one level per brick of the grid.
    #[error("{got} brick levels for a grid of {expected} bricks")]
    LevelCount {
        /// Bricks in the grid.
        expected: usize,
        /// Levels passed.
        got: usize,
    },
    /// The camera cannot be projected.
    #[error("camera: {0}")]
    Camera(#[from] mixvol::lod::LodError),
    /// The SSIM implementation refused the images.
    #[error("SSIM: {0}")]
    Ssim(String),
}

/// A borrowed premultiplied-RGBA frame.
#[derive(Copy, Clone, Debug)]
pub struct Frame<'a> {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height` pixels, row-major, top row first.
    pub pixels: &'a [Vec4],
}

impl<'a> Frame<'a> {
    /// A frame of `width` x `height` over `pixels`, checked.
    pub fn new(width: u32, height: u32, pixels: &'a [Vec4]) -> Result<Self, MetricError> {
        let expected = width as usize * height as usize;
        if pixels.len() != expected {
            return Err(MetricError::SizeMismatch {
                width,
                height,
                expected,
                got: pixels.len(),
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    /// The pixel at column `x`, row `y` (inside the frame).
    pub fn at(&self, x: u32, y: u32) -> Vec4 {
        self.pixels[(y * self.width + x) as usize]
    }

    /// An error unless `other` has this frame's size.
    pub fn check_same_size(&self, other: &Frame<'_>) -> Result<(), MetricError> {
        if (self.width, self.height) != (other.width, other.height) {
            return Err(MetricError::SizeMismatch {
                width: self.width,
                height: self.height,
                expected: self.pixels.len(),
                got: other.pixels.len(),
            });
        }
        Ok(())
    }
}
