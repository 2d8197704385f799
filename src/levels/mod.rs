//! The three-level brick cache on the GPU (issue 19, item 1), filled from a level plan
//! ([`crate::pyramid::LevelPlan`]) and its levels' samples: every drawn brick packed into its slot or sub-slot of a
//! [`SlotGeometry`] cache and uploaded with one `vkCmdCopyBufferToImage` (one region per
//! brick), the border fixup (level 0 towards level 1, `fixup.comp` on the inner box of a
//! `(n+4)^3` slot) and the skeleton fixup (`skeleton_fixup.comp`, level 1 towards level 2) as
//! compute dispatches, and the field read with the ray-caster's own functions (`probe.comp`
//! includes `mixed.glsl`, unchanged: a level-0 brick blends, a coarser one is a plain fetch).
//!
//! The levels come from the host (`renderer::Renderer::set_brick_levels`) or from the
//! camera (`renderer::Renderer::update`, [`crate::plan::choose_levels`]), for a
//! volume in RAM, a level store, or stored bricks streamed in the background
//! ([`crate::store::LevelStreamer`]: a level store, an OME-Zarr pyramid);
//! [`GpuLevelCache`] fills a cache once to read the field and the cache back (the tests check
//! the GPU cache, its fixups and its sampling against the CPU reference's `LevelReferenceCache`).

mod ranges;
mod residency;

pub use ranges::conservative_ranges;
pub use residency::{LevelResidency, LevelUpdate};

use crate::cache::{SlotGeometry, EMPTY};
use crate::error::{Error, Result};
use crate::gpu::{
    CacheRegion, CacheTables, DeviceShared, FieldProbe, GpuBrickCache, GpuContext, SlotPacking,
    StagingUpload, Submitter,
};
use crate::pyramid::{LevelGrid, LevelPacking, LevelPlan};
use crate::scene::Transition;
use crate::volume::ScalarType;
use glam::{UVec3, Vec3};
use std::sync::Arc;

/// A three-level brick cache (f32 texels) on the GPU, filled and fixed up once.
pub struct GpuLevelCache {
    gpu: GpuBrickCache,
    probe: FieldProbe,
    submitter: Submitter,
    // Kept until the cache is dropped: its buffer held the uploaded bricks.
    _staging: StagingUpload,
    dims: UVec3,
    brick_size: u32,
}

/// What one residency change of a three-level source moved
/// (`renderer::Renderer::set_brick_levels`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelUpdateReport {
    /// Stored bricks the new plan draws (one per brick up to level 2, one per block past it).
    pub stored_bricks: usize,
    /// Stored bricks uploaded: new ones, kept ones whose coarser neighbours changed, and kept
    /// ones moved to make room.
    pub uploaded_bricks: usize,
    /// Kept stored bricks moved to another sub-slot to make room for new ones.
    pub moved_bricks: usize,
    /// Bytes uploaded.
    pub uploaded_bytes: usize,
    /// Whether the cache was packed afresh (every stored brick uploaded).
    pub repacked: bool,
    /// CPU time to read or pack the uploaded bricks and stage the change, in milliseconds.
    pub stage_ms: f64,
}

/// What the ray-caster variant needs to know of a staged three-level plan.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) struct LevelPlanFacts {
    /// Some level-0 brick has a level-1 neighbour: the ray-caster's blend is needed.
    pub(crate) any_transition: bool,
    /// Some drawn brick is coarser than level 0.
    pub(crate) any_coarse: bool,
    /// Some brick is not drawn.
    pub(crate) any_absent: bool,
}

/// A GPU cache of `geometry` with the three-level packing, texels of `scalar` (`u8` / `u16`
/// UNORM or f32), tables for `brick_count` bricks and `frames` frame slots.
pub(crate) fn new_three_level_cache(
    shared: &Arc<DeviceShared>,
    geometry: &SlotGeometry,
    scalar: ScalarType,
    brick_count: usize,
    smooth: bool,
    frames: u32,
) -> Result<GpuBrickCache> {
    GpuBrickCache::new(
        shared,
        scalar,
        1,
        geometry.extent(),
        brick_count,
        geometry.slot_count() as usize,
        frames,
        smooth,
        if geometry.classes() == 2 {
            SlotPacking::TwoLevel
        } else {
            SlotPacking::ThreeLevel
        },
    )
}

/// Stages the drawn bricks of `plan` into `gpu` (a cache of `geometry`), packed afresh from
/// the level grids `grids`: [`stage_three_level`] with every stored brick and
/// [`LevelPacking::stored_values`].
fn stage_grids(
    gpu: &mut GpuBrickCache,
    plan: &LevelPlan,
    grids: &[LevelGrid],
    geometry: &SlotGeometry,
) -> Result<LevelPlanFacts> {
    let packed = LevelPacking::for_grids(plan, grids, geometry)?;
    stage_three_level(
        gpu,
        &packed,
        geometry,
        ScalarType::F32,
        &packed.stored,
        &mut |brick| Ok(packed.stored_values(grids, geometry, brick)),
    )
}

/// Stages a residency change of `gpu` (a cache of `geometry` with texels of `scalar`) to
/// `packed`: the stored bricks `upload` (some of [`LevelPacking::stored`]; `texels(brick)`
/// gives each one's `stored_edge^3` normalised values, x fastest, quantised to `scalar` here),
/// not fixed up, the tables of every drawn brick, and the
/// fixup jobs of the uploaded bricks that have coarser neighbours (the GPU runs them when the
/// cache is smooth). Stored bricks not in `upload` must already sit at their places, fixed up
/// for the same coarser bits ([`LevelResidency`]). The next [`GpuBrickCache::record`] uploads
/// them.
pub(crate) fn stage_three_level(
    gpu: &mut GpuBrickCache,
    packed: &LevelPacking,
    geometry: &SlotGeometry,
    scalar: ScalarType,
    upload: &[usize],
    texels: &mut dyn FnMut(usize) -> Result<Vec<f32>>,
) -> Result<LevelPlanFacts> {
    let slot_count = geometry.slot_count() as usize;
    let mut reverse = vec![[EMPTY; crate::bricks::SUB_SLOTS_PER_SLOT as usize]; slot_count];
    let mut any_transition = false;
    let mut any_coarse = false;
    for &brick in &packed.stored {
        match packed.places[brick] {
            Some(place) if place.level == 0 => {
                reverse[place.slot as usize][0] = brick as u32;
                any_transition |= packed.neighbours[brick] != 0;
            }
            Some(_) => any_coarse = true,
            None => {}
        }
    }
    let mut boxes = Vec::with_capacity(upload.len());
    let mut fixup_slots = Vec::new();
    let mut skeleton_bricks = Vec::new();
    for &brick in upload {
        let Some(place) = packed.places[brick] else {
            continue;
        };
        let origin = geometry.origin(place).unwrap_or(UVec3::ZERO);
        let extent = UVec3::splat(geometry.stored_edge(place.level));
        let values = texels(brick)?;
        let expected =
            (crate::cache::stored_brick_edge(geometry.brick_size(), place.level) as usize).pow(3);
        if values.len() != expected {
            return Err(Error::InvalidInput(format!(
                "stored brick {brick} (level {}): {} texels, expected {expected}",
                place.level,
                values.len()
            )));
        }
        // The cache's box of the stored brick (its inner box at level 0 with two classes).
        let values = geometry.cache_texels(place.level, &values);
        boxes.push((origin, extent, crate::bricks::quantize_to(&values, scalar)));
        if place.level == 0 {
            if packed.neighbours[brick] != 0 {
                fixup_slots.push(place.slot);
            }
        } else if packed.block_has_coarser_neighbour(brick) {
            skeleton_bricks.push(brick as u32);
        }
    }
    let regions: Vec<CacheRegion> = boxes
        .iter()
        .map(|(origin, extent, bytes)| CacheRegion {
            origin: *origin,
            extent: *extent,
            bytes,
        })
        .collect();
    let tables = CacheTables {
        layout: &packed.layout,
        neighbours: &packed.neighbours,
        reverse: &reverse,
        fixup_slots: &fixup_slots,
        skeleton_bricks: &skeleton_bricks,
        bricks: packed.bricks,
        brick_size: packed.brick_size,
        slots_per_axis: geometry.slots_per_axis(),
    };
    gpu.stage(&regions, &tables)?;
    Ok(LevelPlanFacts {
        any_transition,
        any_coarse,
        any_absent: packed.places.iter().any(Option::is_none),
    })
}

impl GpuLevelCache {
    /// Packs the drawn bricks of `plan` (with the samples of the level grids `grids`, levels
    /// 0, 1, ... in order) into a cache of `geometry`, uploads them and, for
    /// [`Transition::Smooth`], runs the border and skeleton fixups on the GPU; waits for the
    /// GPU. The volume's extent is level 0's.
    ///
    /// Errors: what [`LevelPacking::for_grids`] refuses (more than three levels, other sample
    /// placements, another brick size, more slots than the cache has), a cache image the device
    /// cannot create, or a failed submission.
    pub fn new(
        ctx: &GpuContext,
        plan: &LevelPlan,
        grids: &[LevelGrid],
        geometry: &SlotGeometry,
        transition: Transition,
    ) -> Result<Self> {
        let shared = &ctx.shared;
        let smooth = transition == Transition::Smooth;
        let dims = match grids.first() {
            Some(level0) if grids.len() == plan.level_count() as usize => level0.dims(),
            _ => {
                return Err(Error::InvalidInput(format!(
                    "{} level grids for a plan of {} levels",
                    grids.len(),
                    plan.level_count()
                )))
            }
        };
        let brick_count = plan.bricks_per_axis().element_product() as usize;
        let mut gpu =
            new_three_level_cache(shared, geometry, ScalarType::F32, brick_count, smooth, 1)?;
        stage_grids(&mut gpu, plan, grids, geometry)?;
        let mut submitter = Submitter::new(shared)?;
        let mut staging = StagingUpload::new(shared, "three-level bricks");
        submitter.run(|_, cmd| gpu.record(cmd, 0, &mut staging, None).map(|_| ()))?;
        let probe = FieldProbe::new(shared, smooth)?;
        Ok(Self {
            gpu,
            probe,
            submitter,
            _staging: staging,
            dims,
            brick_size: plan.brick_size(),
        })
    }

    /// The field at volume points (hi-res voxel units), read with the ray-caster's functions;
    /// `None` where a point lies in a brick that is not drawn.
    pub fn sample(&mut self, points: &[Vec3]) -> Result<Vec<Option<f32>>> {
        self.probe.sample(
            &mut self.submitter,
            &mut self.gpu,
            0,
            self.dims,
            self.brick_size,
            points,
        )
    }

    /// The cache image read back (texels, x fastest).
    pub fn read_back(&mut self) -> Result<Vec<f32>> {
        let bytes = self.gpu.read_back(&mut self.submitter)?;
        Ok(crate::bricks::dequantize(&bytes, ScalarType::F32))
    }
}
