//! The resolution level of one brick: what the LOD selector wants, what the brick cache stores and
//! what a [`BrickSource`](super::BrickSource) packs.

/// The resolution level the LOD selector wants for a brick.
///
/// One byte (`repr(u8)`: `Hi` 0, `Lo` 1, `Absent` 2), so that slices of levels can be compared
/// and counted as bytes.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, bytemuck::NoUninit)]
#[repr(u8)]
pub enum Level {
    /// Level 0: the full-resolution brick, `(n+2)^3` texels, one whole slot.
    Hi,
    /// Level 1: the half-resolution brick, `(n/2+1)^3` texels, one sub-slot.
    Lo,
    /// Not drawn (culled or not resident); no cache storage.
    #[default]
    Absent,
}

impl Level {
    /// The level's number in the one level system (levels counted from the finest): `Hi` 0, `Lo` 1,
    /// `Absent` none.
    pub fn number(self) -> Option<u32> {
        match self {
            Level::Hi => Some(0),
            Level::Lo => Some(1),
            Level::Absent => None,
        }
    }

    /// True for `Hi` and `Lo`.
    pub fn is_resident(self) -> bool {
        self != Level::Absent
    }
}
