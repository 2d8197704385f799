//! The error type of the level-of-detail module.

/// Everything that can go wrong while culling bricks or selecting their levels.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LodError {
    /// The transfer-function value window is not finite, or so narrow that `1 / (hi - lo)`
    /// overflows, or its inverse range is negative or not finite.
    #[error("value window lo = {lo}, inverse range = {inv_range} is unusable (must be finite, inverse range >= 0)")]
    InvalidWindow {
        /// Window low end.
        lo: f32,
        /// `1 / (hi - lo)` (0 for an empty window).
        inv_range: f32,
    },
    /// The iso-value is not finite.
    #[error("iso-value {iso} is not finite")]
    InvalidIsoValue {
        /// The iso-value given.
        iso: f32,
    },
    /// A per-brick input does not hold one entry per brick.
    #[error("{what} holds {actual} entries but the brick grid has {expected} bricks")]
    LengthMismatch {
        /// Which input (`"value ranges"`, `"active mask"`, `"levels"`).
        what: &'static str,
        /// Number of bricks in the grid.
        expected: usize,
        /// Number of entries given.
        actual: usize,
    },
    /// The voxel spacing is not positive and finite.
    #[error("voxel spacing {spacing:?} must be positive and finite on every axis")]
    InvalidSpacing {
        /// The spacing given.
        spacing: [f32; 3],
    },
    /// The image has a zero side.
    #[error("image {width}x{height} has a zero side")]
    ZeroViewport {
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
    },
    /// The camera has no usable view frame (eye equals target, up parallel to the view
    /// direction, non-finite values, or a bad near/far pair).
    #[error("degenerate camera: {reason}")]
    DegenerateCamera {
        /// What is wrong.
        reason: &'static str,
    },
    /// The projection is unusable (field of view outside (0, 180) degrees, or a non-positive
    /// orthographic height).
    #[error("unusable projection: {reason}")]
    InvalidProjection {
        /// What is wrong.
        reason: &'static str,
    },
    /// A selection filter parameter is negative or not finite.
    #[error("{filter} filter parameter {value} must be finite and >= 0")]
    InvalidFilter {
        /// The filter (`"distance"` or `"field-of-view"`).
        filter: &'static str,
        /// The parameter given.
        value: f32,
    },
    /// Even with every active brick at low resolution the cache has too few slots.
    #[error(
        "cache budget too small: {active} active bricks need at least {needed} slots \
         (eight low-res bricks per slot) but only {slots} are available"
    )]
    BudgetTooSmall {
        /// Number of active (not culled) bricks.
        active: usize,
        /// Slots needed with every active brick low-res: `ceil(active / 8)`.
        needed: usize,
        /// Slots available.
        slots: usize,
    },
}
