//! mixvol: a Vulkan-native, explicitly memory-managed volume ray-caster.
//!
//! The library prints nothing and parses no command line: the `mixvol` tool is the
//! `mixvol-cli` crate, the papers' experiments and reports are `mixvol-experiments`. Long work
//! reports progress through callbacks the caller may turn into a bar.
//!
//! Modules, one per concept:
//! - [`volume`]: voxel storage, synthetic fields, loaders.
//! - [`optics`]: transfer functions, opacity correction, compositing.
//! - [`scene`]: camera, render settings and the per-frame parameter block.
//! - [`reference`](mod@reference): the CPU reference ray-caster (the oracle for every GPU test).
//! - [`gpu`]: the ash backend (context, memory, uploads, shaders and the definitions they share
//!   with Rust, ray-cast pipeline).
//! - [`embed`]: the volume pass recorded into a host engine's command buffers.
//! - [`renderer`]: the offscreen façade that turns a volume + scene into an image.
//! - [`store`]: the on-disk brick store (preprocessing) and background brick streaming.
//! - [`plan`]: camera-driven residency planning: the levels to draw and load each frame under
//!   cache, upload and RAM budgets.
#![warn(
    missing_docs,
    unsafe_op_in_unsafe_fn,
    clippy::undocumented_unsafe_blocks
)]

pub mod bricks;
pub mod cache;
pub mod embed;
pub mod error;
pub mod gpu;
pub mod levels;
pub mod lod;
pub mod optics;
pub mod output;
pub mod plan;
pub mod pyramid;
pub mod reference;
pub mod renderer;
pub mod scene;
pub mod store;
pub mod stream;
pub mod volume;

pub use error::{Error, Result};
