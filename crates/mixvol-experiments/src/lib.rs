//! The papers' experiments and reports, built on the `mixvol` library and kept out of it:
//!
//! - [`kraus`]: Kraus & Bürger's opacity- vs extinction-based sampling experiments (CPU), the
//!   report behind `mixvol kraus` (`docs/report/kraus.*`).
//! - [`accuracy`]: the accuracy-versus-time report behind `mixvol report`
//!   (`docs/report/accuracy-vs-time.*`, `docs/report/seams-vs-time.*`): one scene under every
//!   setting that trades accuracy for time, against a high-quality reference.
//! - [`junction`]: the accuracy report's close-up of an edge-on hi/lo junction (its transition
//!   rows).
//! - [`metrics`]: the image metrics of the accuracy report (RMSE/PSNR, gradient error, SSIM,
//!   the seam measure).
//! - [`scenes`]: the accuracy report over several scenes (Marschner-Lobb, MNI152, the VolPack
//!   head), each from an orbit of views, mean and worst over the views.
//! - [`capacity`]: how large a volume each level scheme can draw in a given cache (texels per
//!   voxel per level, the largest volume at the coarsest level), `docs/report/capacity.md`.
//! - [`plot`]: the charts of both reports (plotters, PNG and SVG).
//! - [`oracle`]: the CPU reference image of what a renderer drew (`mixvol render --compare`).
#![warn(missing_docs)]

pub mod accuracy;
pub mod capacity;
pub mod junction;
pub mod kraus;
pub mod metrics;
pub mod oracle;
pub mod plot;
pub mod scenes;
