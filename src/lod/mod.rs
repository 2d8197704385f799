//! Level of detail for flat two-level bricking: which bricks to draw, and at which resolution.
//!
//! Each frame, in two CPU passes over the brick grid:
//!
//! 1. [`culling`]: a brick is *active* when it can contribute to the image: its value range
//!    reaches a visible transfer-function entry ([`TfCullTable`], O(1) per brick via a prefix
//!    count) or contains the iso-value ([`iso_active`]), and no clip plane removes it
//!    ([`ClipPlanes`](crate::scene::ClipPlanes)). [`cull_bricks`] yields the active mask.
//! 2. [`selection`]: every active brick is drawn at least low-res; a screen-space error ranking
//!    promotes bricks to hi-res while the cache budget `#Hi + ceil(#Lo / 8) <= slots` holds
//!    (Beyer et al. 2008), optionally restricted by LaMar et al.'s (1999) distance and
//!    field-of-view filters. [`select_levels`] / [`LodSelector`] yield one
//!    [`Level`](crate::bricks::Level) per brick (`Absent` for culled bricks), the input of the
//!    cache layout (`docs/cache-layout.md`).
//!
//! [`BrickGeometry`] places the brick grid in world space ([`crate::scene::volume_box`]) and
//! [`LodView`] holds the camera as both passes need it. Everything here is CPU-only.

pub mod culling;
mod error;
pub mod geometry;
pub mod selection;

pub use culling::{
    cull_bricks, cull_bricks_into, iso_active, CullParams, TfCullTable, ValueCulling,
};
pub use error::LodError;
pub use geometry::{BrickGeometry, LodView, ViewProjection};
pub use selection::{
    check_level_rule, check_level_rule_with, level_number, max_hi_bricks, screen_space_error,
    select_levels, slots_needed, DistanceFilter, FovFilter, LodSelector, SelectionOptions,
    SelectionSummary,
};
