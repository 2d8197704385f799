//! How large a volume a level scheme can draw in a given cache (issue 19, item 5): the texels a
//! brick stores per voxel it represents at each level, and the largest volume a cache of a given
//! size can hold with every brick at its coarsest level.
//!
//! Three schemes:
//! - [`Scheme::TwoLevel`], the one `mixvol` builds: `(n+2)^3` slots holding one level-0 brick or
//!   eight `(n/2+1)^3` level-1 bricks. Its slot and sub-slot extents are read from the library
//!   ([`hi_res_brick_extent`], [`low_res_brick_extent`], [`SUB_SLOTS_PER_SLOT`]).
//! - [`Scheme::ThreeLevel`], Beyer et al. §3.1, which `mixvol` builds too
//!   ([`mixvol::cache::SlotGeometry`], drawn through `VolumeSource::Levels`): `(n+4)^3`
//!   slots holding one level-0 brick, eight `(n/2+2)^3` level-1 bricks or sixty-four
//!   `(n/4+1)^3` level-2 bricks. Its slot and sub-slot extents are read from the library too.
//! - [`Scheme::Blocks`], the three-level packing with the block levels past 2 that `mixvol`
//!   builds as well: a level-`k` brick of the level-2 size stands for an aligned block of
//!   `2^(k - 2)` bricks per axis ([`mixvol::cache::block_bricks`]). Shown up to level
//!   [`BLOCK_LEVELS`]` - 1`; there is no limit but the volume's.
//!
//! The cache is an image with a power of two texels on every axis, at most `max_dim_3d`
//! (`maxImageDimension3D`) each, under a byte budget, and holds whole slots only, as
//! [`mixvol::cache::CacheGeometry::choose`] lays it out: [`most_slots`] finds the extent with the
//! most slots of a given edge the same way (a test checks it against `choose` for the two-level
//! slot).

use mixvol::bricks::{hi_res_brick_extent, low_res_brick_extent, SUB_SLOTS_PER_SLOT};
use mixvol::cache::block_bricks;
use mixvol::cache::{SlotGeometry, THREE_LEVELS};

/// Levels of [`Scheme::Blocks`] in the report (0-5: blocks of up to 8^3 bricks).
pub const BLOCK_LEVELS: u32 = 6;
use std::fmt::Write as _;

/// A way of packing brick levels into cache slots.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// `(n+2)^3` slots: one level-0 brick or eight level-1 bricks (built).
    TwoLevel,
    /// `(n+4)^3` slots: one level-0, eight level-1 or 64 level-2 bricks (the paper's §3.1;
    /// built).
    ThreeLevel,
    /// The three-level packing with levels past 2 as blocks of bricks (built).
    Blocks,
}

impl Scheme {
    /// Every scheme, in the order they were built.
    pub const ALL: [Scheme; 3] = [Scheme::TwoLevel, Scheme::ThreeLevel, Scheme::Blocks];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::TwoLevel => "two levels, (n+2)^3 slots (built)",
            Scheme::ThreeLevel => "three levels, (n+4)^3 slots (paper §3.1, built)",
            Scheme::Blocks => "block levels past 2, (n+4)^3 slots (built)",
        }
    }

    /// The slot edge in texels for bricks of `n` voxels.
    pub fn slot_edge(self, n: u32) -> u32 {
        match self {
            Scheme::TwoLevel => hi_res_brick_extent(n),
            Scheme::ThreeLevel | Scheme::Blocks => three_level(n).slot_edge(),
        }
    }

    /// For each level (0 = full resolution): the edge of its stored brick in texels and how many
    /// of them one slot holds.
    pub fn levels(self, n: u32) -> Vec<(u32, u32)> {
        match self {
            Scheme::TwoLevel => vec![
                (hi_res_brick_extent(n), 1),
                (low_res_brick_extent(n), SUB_SLOTS_PER_SLOT),
            ],
            Scheme::ThreeLevel | Scheme::Blocks => {
                let geometry = three_level(n);
                let levels = if self == Scheme::Blocks {
                    BLOCK_LEVELS
                } else {
                    THREE_LEVELS
                };
                (0..levels)
                    .map(|k| (geometry.sub_slot_edge(k), SlotGeometry::bricks_per_slot(k)))
                    .collect()
            }
        }
    }
}

impl Scheme {
    /// Bricks per axis one stored brick of `level` stands for: 1, or the block of
    /// [`Scheme::Blocks`].
    pub fn block(self, level: u32) -> u32 {
        match self {
            Scheme::Blocks => block_bricks(level),
            Scheme::TwoLevel | Scheme::ThreeLevel => 1,
        }
    }
}

/// The library's three-level geometry for bricks of `n` voxels (one slot; only its slot and
/// sub-slot extents are read). `n` is a power of two of at least 4, as everywhere here.
fn three_level(n: u32) -> SlotGeometry {
    let edge = (n + 4).next_power_of_two();
    SlotGeometry::new(n, 3, glam::UVec3::splat(edge))
        .expect("a power-of-two brick size of at least 4 has a three-level slot")
}

/// What one level of a scheme costs.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LevelCost {
    /// The level (0 = full resolution).
    pub level: u32,
    /// Cache texels one stored brick of this level takes: its share of a slot.
    pub texels_per_brick: f64,
    /// Cache texels per voxel of the volume the stored brick represents (`(block n)^3` voxels).
    pub texels_per_voxel: f64,
}

/// The cost of every level of `scheme` for bricks of `n` voxels (a power of two, at least 8 so
/// that a level-2 brick has whole voxels).
pub fn level_costs(scheme: Scheme, n: u32) -> Vec<LevelCost> {
    let slot = f64::from(scheme.slot_edge(n)).powi(3);
    scheme
        .levels(n)
        .iter()
        .enumerate()
        .map(|(level, &(_, per_slot))| {
            let texels_per_brick = slot / f64::from(per_slot);
            let voxels = f64::from(scheme.block(level as u32) * n).powi(3);
            LevelCost {
                level: level as u32,
                texels_per_brick,
                texels_per_voxel: texels_per_brick / voxels,
            }
        })
        .collect()
}

/// The power-of-two extent (each axis at most `max_dim_3d`, texels times `bytes_per_texel`
/// within `byte_budget`) that holds the most whole slots of edge `slot_edge`; ties go to fewer
/// texels. `None` when not even one slot fits.
pub fn most_slots(
    slot_edge: u32,
    bytes_per_texel: u32,
    byte_budget: u64,
    max_dim_3d: u32,
) -> Option<([u32; 3], u64)> {
    let min_axis = slot_edge.next_power_of_two();
    let axes: Vec<u32> = std::iter::successors(Some(min_axis), |&c| c.checked_mul(2))
        .take_while(|&c| c <= max_dim_3d)
        .collect();
    let mut best: Option<([u32; 3], u64, u128)> = None;
    for &x in &axes {
        for &y in &axes {
            for &z in &axes {
                let texels = u128::from(x) * u128::from(y) * u128::from(z);
                if texels * u128::from(bytes_per_texel) > u128::from(byte_budget) {
                    continue;
                }
                let slots = [x, y, z]
                    .iter()
                    .map(|&c| u64::from(c / slot_edge))
                    .product::<u64>();
                let better = best
                    .as_ref()
                    .is_none_or(|&(_, s, t)| slots > s || (slots == s && texels < t));
                if better {
                    best = Some(([x, y, z], slots, texels));
                }
            }
        }
    }
    best.map(|(e, s, _)| (e, s))
}

/// The largest volume a cache can draw under one scheme, every brick at the coarsest level.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Capacity {
    /// The cache extent with the most slots ([`most_slots`]).
    pub extent: [u32; 3],
    /// Its slots.
    pub slots: u64,
    /// Stored bricks it holds at the coarsest level.
    pub bricks: u64,
    /// Voxels those bricks represent (`bricks * (block n)^3`).
    pub voxels: u64,
}

/// The capacity of a cache of `byte_budget` bytes under `scheme`; `None` when no slot fits.
pub fn capacity(
    scheme: Scheme,
    n: u32,
    bytes_per_texel: u32,
    byte_budget: u64,
    max_dim_3d: u32,
) -> Option<Capacity> {
    let (extent, slots) = most_slots(
        scheme.slot_edge(n),
        bytes_per_texel,
        byte_budget,
        max_dim_3d,
    )?;
    let levels = scheme.levels(n);
    let per_slot = levels.last().map_or(1, |&(_, k)| u64::from(k));
    let block = u64::from(scheme.block(levels.len().saturating_sub(1) as u32));
    let bricks = slots * per_slot;
    Some(Capacity {
        extent,
        slots,
        bricks,
        voxels: bricks * (block * u64::from(n)).pow(3),
    })
}

/// The report as Markdown: texels per voxel for every level of both schemes at n = 16, 32, 64,
/// and the largest volume each can draw in a cache of `byte_budget` bytes of `bytes_per_texel`
/// texels (with `max_dim_3d` per axis).
pub fn report(bytes_per_texel: u32, byte_budget: u64, max_dim_3d: u32) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Texels stored per voxel represented (a stored brick's share of its slot over the \
         voxels it stands for: n^3, or (block n)^3 for the block levels):\n"
    );
    let _ = write!(s, "| scheme | n |");
    for level in 0..BLOCK_LEVELS {
        let _ = write!(s, " level {level} |");
    }
    let _ = writeln!(s, "\n|---|---|{}", "---|".repeat(BLOCK_LEVELS as usize));
    for scheme in Scheme::ALL {
        for n in [16, 32, 64] {
            let costs = level_costs(scheme, n);
            let cell = |l: usize| {
                costs.get(l).map_or("-".to_string(), |c| {
                    if c.texels_per_voxel >= 1e-3 {
                        format!(
                            "{:.4} ({:.0} texels)",
                            c.texels_per_voxel, c.texels_per_brick
                        )
                    } else {
                        format!(
                            "{:.2e} ({:.0} texels)",
                            c.texels_per_voxel, c.texels_per_brick
                        )
                    }
                })
            };
            let _ = write!(s, "| {} | {n} |", scheme.name());
            for level in 0..BLOCK_LEVELS as usize {
                let _ = write!(s, " {} |", cell(level));
            }
            let _ = writeln!(s);
        }
    }
    let _ = writeln!(
        s,
        "\nThe largest volume a cache of {:.1} GiB ({bytes_per_texel} byte(s) per texel, at most \
         {max_dim_3d} texels per axis) can draw, every brick at the coarsest level:\n",
        byte_budget as f64 / f64::from(1u32 << 30)
    );
    let _ = writeln!(
        s,
        "| scheme | n | cache extent | slots | bricks | voxels | GiB at {bytes_per_texel} byte(s) per voxel | x the cache |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for scheme in Scheme::ALL {
        for n in [16, 32, 64] {
            let Some(c) = capacity(scheme, n, bytes_per_texel, byte_budget, max_dim_3d) else {
                let _ = writeln!(s, "| {} | {n} | no slot fits | | | | | |", scheme.name());
                continue;
            };
            let bytes = c.voxels as f64 * f64::from(bytes_per_texel);
            let _ = writeln!(
                s,
                "| {} | {n} | {}x{}x{} | {} | {} | {:.3e} | {:.1} | {:.1} |",
                scheme.name(),
                c.extent[0],
                c.extent[1],
                c.extent[2],
                c.slots,
                c.bricks,
                c.voxels as f64,
                bytes / f64::from(1u32 << 30),
                bytes / byte_budget as f64,
            );
        }
    }
    s
}
