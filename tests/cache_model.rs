//! End-to-end tests of the CPU cache model on awkward volumes: parallel bricking
//! (`bricks::build_bricks`) -> transfer-function culling -> LOD selection under a slot budget ->
//! `BrickCache::update` -> tables, checked against `docs/cache-layout.md`.
//!
//! Every scenario also replays the upload lists into a CPU copy of the cache image (packed bricks
//! from the `PackedBricks`) and reads every owned voxel and every low-res sample of every resident
//! brick back through its layout entry, so the upload list, the packed data and the layout table
//! have to agree. CPU only.

use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{
    build_bricks, low_res_level, quantize_to, BrickGrid, DownsampleFilter, Level, LowResLevel,
    PackedBricks,
};
use mixvol::cache::{
    compute_neighbour_bits, BrickCache, CacheError, CacheGeometry, CacheUpdate, Residency, EMPTY,
};
use mixvol::lod::{
    cull_bricks, screen_space_error, slots_needed, BrickGeometry, CullParams, LodError,
    LodSelector, LodView, SelectionOptions, TfCullTable,
};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::Camera;
use mixvol::volume::{ScalarType, Volume, VoxelData};
use std::collections::BTreeSet;

/// Neighbour bits of every brick of a `bricks` grid (x fastest) for `levels`, computed directly
/// (see `check_tables`).
fn independent_neighbour_bits(bricks: UVec3, levels: &[Level]) -> Vec<u32> {
    let (nx, ny, nz) = (bricks.x as i32, bricks.y as i32, bricks.z as i32);
    let at = |x: i32, y: i32, z: i32| levels[(x + nx * (y + ny * z)) as usize];
    let mut out = Vec::with_capacity(levels.len());
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let mut bits = 0u32;
                if at(x, y, z) == Level::Hi {
                    for dz in -1..=1 {
                        for dy in -1..=1 {
                            for dx in -1..=1 {
                                let (u, v, w) = (x + dx, y + dy, z + dz);
                                if (dx, dy, dz) == (0, 0, 0)
                                    || !(0..nx).contains(&u)
                                    || !(0..ny).contains(&v)
                                    || !(0..nz).contains(&w)
                                    || at(u, v, w) != Level::Lo
                                {
                                    continue;
                                }
                                let idx = (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1);
                                let k = if idx < 13 { idx } else { idx - 1 };
                                bits |= 1 << k;
                            }
                        }
                    }
                }
                out.push(bits);
            }
        }
    }
    out
}

/// The independent computation on a hand-checked 3 x 2 x 1 grid: the hi-res brick (0, 0, 0) with
/// low-res neighbours (1, 0, 0) (offset +x: idx 14, bit 13) and (1, 1, 0) (offset +x+y: idx 17,
/// bit 16); the absent brick (0, 1, 0) sets nothing, and lo-res bricks have no bits.
#[test]
fn independent_neighbour_bits_by_hand() {
    use Level::{Absent, Hi, Lo};
    let levels = [Hi, Lo, Hi, Absent, Lo, Lo];
    let bits = independent_neighbour_bits(UVec3::new(3, 2, 1), &levels);
    // Brick (2, 0, 0): neighbours (1, 0, 0) at -x (idx 12, bit 12), (1, 1, 0) at -x+y (idx 15,
    // bit 14) and (2, 1, 0) at +y (idx 16, bit 15), all low-res.
    assert_eq!(
        bits,
        vec![
            (1 << 13) | (1 << 16),
            0,
            (1 << 12) | (1 << 14) | (1 << 15),
            0,
            0,
            0
        ]
    );
}

const WIDTH: u32 = 640;
const HEIGHT: u32 = 480;

/// Deterministic values in [0, 1) (xorshift).
fn noise(count: usize, seed: u64) -> Vec<f32> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..count)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

/// A volume of `dims` whose values are `f(voxel, noise)`, stored as `scalar`.
fn volume(dims: UVec3, scalar: ScalarType, seed: u64, f: impl Fn(UVec3, f32) -> f32) -> Volume {
    let n = noise((dims.x * dims.y * dims.z) as usize, seed);
    let mut values = Vec::with_capacity(n.len());
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                values.push(f(UVec3::new(x, y, z), n[values.len()]).clamp(0.0, 1.0));
            }
        }
    }
    let data = match scalar {
        ScalarType::U8 => VoxelData::U8(values.iter().map(|v| (v * 255.0).round() as u8).collect()),
        ScalarType::U16 => VoxelData::U16(
            values
                .iter()
                .map(|v| (v * 65535.0).round() as u16)
                .collect(),
        ),
        ScalarType::F32 => VoxelData::F32(values),
    };
    Volume::new(dims, Vec3::ONE, data).unwrap()
}

/// A CPU copy of the cache image, filled only through upload lists.
struct CacheImage {
    extent: UVec3,
    bytes_per_texel: usize,
    data: Vec<u8>,
    /// Texels written at least once.
    written: Vec<bool>,
}

impl CacheImage {
    fn new(geometry: &CacheGeometry, storage: ScalarType) -> Self {
        let texels = geometry.texel_count() as usize;
        assert!(texels <= 1 << 24, "test cache image too large: {texels}");
        Self {
            extent: geometry.extent(),
            bytes_per_texel: storage.size_bytes(),
            data: vec![0; texels * storage.size_bytes()],
            written: vec![false; texels],
        }
    }

    fn index(&self, t: UVec3) -> usize {
        assert!(
            t.cmplt(self.extent).all(),
            "texel {t} outside {}",
            self.extent
        );
        (t.x + self.extent.x * (t.y + self.extent.y * t.z)) as usize
    }

    /// Applies an update: packs each listed brick from the store, as the GPU backend does.
    fn apply(&mut self, update: &CacheUpdate, store: &PackedBricks) {
        for upload in &update.uploads {
            let packed = match upload.level {
                Level::Hi => store.hi_res_brick(upload.brick as usize),
                Level::Lo => store.low_res_brick(upload.brick as usize),
                Level::Absent => panic!("upload of an absent brick {}", upload.brick),
            }
            .expect("brick inside the grid");
            let e = UVec3::from_array(upload.extent);
            assert_eq!(
                packed.len(),
                (e.x * e.y * e.z) as usize * self.bytes_per_texel
            );
            let o = UVec3::from_array(upload.dst_origin);
            let bpt = self.bytes_per_texel;
            for z in 0..e.z {
                for y in 0..e.y {
                    for x in 0..e.x {
                        let src = (x + e.x * (y + e.y * z)) as usize * bpt;
                        let dst = self.index(o + UVec3::new(x, y, z));
                        self.data[dst * bpt..(dst + 1) * bpt]
                            .copy_from_slice(&packed[src..src + bpt]);
                        self.written[dst] = true;
                    }
                }
            }
        }
    }

    /// The texel containing the (texel-unit) coordinate `tex`.
    fn texel(&self, tex: Vec3) -> &[u8] {
        let i = self.index(tex.floor().as_uvec3());
        assert!(self.written[i], "texel at {tex} was never uploaded");
        &self.data[i * self.bytes_per_texel..(i + 1) * self.bytes_per_texel]
    }
}

/// One pipeline: volume, bricks, culling and a cache with its CPU image.
struct Pipeline {
    volume: Volume,
    grid: BrickGrid,
    store: PackedBricks,
    level: LowResLevel,
    geometry: BrickGeometry,
    active: Vec<bool>,
    options: SelectionOptions,
    selector: LodSelector,
    cache: BrickCache,
    image: CacheImage,
    levels: Vec<Level>,
}

impl Pipeline {
    /// Bricks `volume` with `n`, culls with the grey TF (value 0 is transparent) and sets up a
    /// cache of at most `cache_bytes` holding `max_slots` usable slots (or every slot).
    fn new(
        volume: Volume,
        n: u32,
        filter: DownsampleFilter,
        storage: ScalarType,
        cache_bytes: u64,
        max_slots: Option<u32>,
    ) -> Self {
        let grid = BrickGrid::new(volume.dims(), n).unwrap();
        let store = build_bricks(&volume, &grid, filter, storage).unwrap();
        assert_eq!(store.value_ranges().len(), grid.brick_count());
        let level = low_res_level(&volume, filter);
        assert_eq!(store.low_res_level(), &level);
        let geometry = BrickGeometry::new(grid, volume.spacing()).unwrap();
        let tf = TransferFunction::preset(TfPreset::Grey);
        let params = CullParams::transfer_function(TfCullTable::new(&tf, (0.0, 1.0)).unwrap());
        let active = cull_bricks(&geometry, store.value_ranges(), &params).unwrap();
        let wanted = grid.brick_count() as u32;
        let bpt = storage.size_bytes() as u32;
        let cache_geometry = CacheGeometry::choose(n, bpt, cache_bytes, 2048, wanted).unwrap();
        let cache = match max_slots {
            Some(s) => BrickCache::with_slot_limit(grid, cache_geometry, s).unwrap(),
            None => BrickCache::new(grid, cache_geometry).unwrap(),
        };
        let options = SelectionOptions::with_slots(cache.capacity() as usize);
        let image = CacheImage::new(&cache_geometry, storage);
        Self {
            volume,
            grid,
            store,
            level,
            geometry,
            active,
            options,
            selector: LodSelector::new(),
            cache,
            image,
            levels: Vec::new(),
        }
    }

    fn view(camera: &Camera) -> LodView {
        LodView::new(camera, WIDTH, HEIGHT).unwrap()
    }

    /// Selects levels for `camera`, updates the cache, replays the uploads and checks everything.
    fn frame(&mut self, camera: &Camera) -> CacheUpdate {
        let view = Self::view(camera);
        let before = self.cache.residencies().to_vec();
        let summary = self
            .selector
            .select_into(
                &self.geometry,
                &view,
                self.store.value_ranges(),
                &self.active,
                &self.options,
                &mut self.levels,
            )
            .unwrap();
        let hi = self.levels.iter().filter(|&&l| l == Level::Hi).count();
        let lo = self.levels.iter().filter(|&&l| l == Level::Lo).count();
        assert_eq!((summary.hi, summary.lo), (hi, lo));
        assert!(
            hi + lo.div_ceil(8) <= self.cache.capacity() as usize,
            "{hi} hi + {lo} lo over {} slots",
            self.cache.capacity()
        );
        for (i, (&level, &active)) in self.levels.iter().zip(&self.active).enumerate() {
            assert_eq!(level.is_resident(), active, "brick {i}: culled iff absent");
        }
        let update = self.cache.update(&self.levels).unwrap();
        assert_eq!(self.cache.levels(), self.levels);
        self.image.apply(&update, &self.store);
        self.check_update(&before, &update);
        self.check_tables();
        self.check_image();
        update
    }

    /// The upload list is exactly the changed residencies plus the border restores.
    fn check_update(&self, before: &[Residency], update: &CacheUpdate) {
        let uploaded: BTreeSet<u32> = update.uploads.iter().map(|u| u.brick).collect();
        assert_eq!(
            uploaded.len(),
            update.uploads.len(),
            "a brick uploaded twice"
        );
        let restored: BTreeSet<u32> = update.restored_borders.iter().copied().collect();
        for (i, (&old, &new)) in before.iter().zip(self.cache.residencies()).enumerate() {
            let i = i as u32;
            let changed = old != new && new != Residency::Absent;
            assert_eq!(
                uploaded.contains(&i),
                changed || restored.contains(&i),
                "brick {i}: {old:?} -> {new:?}"
            );
            assert_eq!(
                update.evicted.contains(&i),
                old != Residency::Absent && new == Residency::Absent
            );
        }
        for upload in &update.uploads {
            let (origin, extent) = self
                .cache
                .geometry()
                .texel_box(self.cache.residency(upload.brick))
                .unwrap();
            assert_eq!(upload.dst_origin, origin.to_array());
            assert_eq!(upload.extent, extent.to_array());
            assert_eq!(upload.level, self.levels[upload.brick as usize]);
        }
    }

    /// Layout, reverse table and neighbour bits against the residency and the layout contract.
    fn check_tables(&self) {
        let g = *self.cache.geometry();
        let n = self.grid.brick_size();
        let dims = self.grid.dims();
        let layout = self.cache.layout_table();
        let reverse = self.cache.reverse_table();
        let mut places = BTreeSet::new();
        for (i, &r) in self.cache.residencies().iter().enumerate() {
            let entry = layout[i];
            let Some((origin, extent)) = g.texel_box(r) else {
                assert_eq!(entry, [0.0; 4], "absent brick {i}");
                continue;
            };
            assert!((origin + extent).cmple(g.extent()).all(), "brick {i}");
            let b = self.grid.brick_coords(i);
            // The centre and every corner of the brick's (clipped) box map into its texel box.
            let lo = (b * n).as_vec3();
            let hi = ((b + UVec3::ONE) * n).min(dims).as_vec3();
            let map = |p: Vec3| p * entry[3] + Vec3::new(entry[0], entry[1], entry[2]);
            let (o, e) = (origin.as_vec3(), extent.as_vec3());
            let centre = map(0.5 * (lo + hi));
            assert!(
                centre.cmpgt(o).all() && centre.cmplt(o + e).all(),
                "brick {i} ({r:?}): centre -> {centre} outside {origin} + {extent}"
            );
            for c in 0..8 {
                let corner =
                    Vec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), hi, lo);
                let t = map(corner);
                assert!(t.cmpge(o).all() && t.cmple(o + e).all(), "brick {i} corner");
            }
            match r {
                Residency::Hi { slot } => {
                    assert_eq!(entry[3], 1.0);
                    assert_eq!(reverse[slot as usize][0], i as u32);
                    assert!(reverse[slot as usize][1..].iter().all(|&x| x == EMPTY));
                    assert!(places.insert((slot, 8)), "slot {slot} reused");
                }
                Residency::Lo { slot, sub_slot } => {
                    assert_eq!(entry[3], 0.5);
                    assert_eq!(reverse[slot as usize][sub_slot as usize], i as u32);
                    assert!(!places.contains(&(slot, 8)), "hi slot {slot} also split");
                    assert!(places.insert((slot, sub_slot)), "sub-slot reused");
                }
                Residency::Absent => unreachable!(),
            }
        }
        // The neighbour bits against a computation written here from the levels and the bit
        // numbering of docs/cache-layout.md (not through `brick_neighbour_bits`, which both
        // library functions use): bit `k` of a hi-res brick is set when its neighbour at offset
        // `d` is inside the grid and low-res, `idx = (dx+1) + 3(dy+1) + 9(dz+1)`, `k = idx` below
        // 13 and `idx - 1` above; lo-res and absent bricks have no bits.
        let bits = self.cache.neighbour_bits();
        let expected = independent_neighbour_bits(self.grid.bricks_per_axis(), &self.levels);
        assert_eq!(bits.len(), expected.len());
        for (i, (got, want)) in bits.iter().zip(&expected).enumerate() {
            assert_eq!(
                got,
                want,
                "brick {i} ({:?}, {:?}): neighbour bits {got:#028b}, expected {want:#028b}",
                self.grid.brick_coords(i),
                self.levels[i]
            );
        }
        assert_eq!(
            compute_neighbour_bits(&self.grid, &self.levels),
            expected,
            "compute_neighbour_bits"
        );
    }

    /// Reads every owned voxel (hi-res) / low-res sample (low-res) of every resident brick
    /// through the layout table from the replayed cache image.
    fn check_image(&self) {
        let storage = self.store.storage();
        let n = self.grid.brick_size() as i32;
        let kmax = self.level.dims.as_ivec3() - IVec3::ONE;
        let layout = self.cache.layout_table();
        for (i, &level) in self.levels.iter().enumerate() {
            let entry = layout[i];
            let map = |p: Vec3| p * entry[3] + Vec3::new(entry[0], entry[1], entry[2]);
            let b = self.grid.brick_coords(i);
            match level {
                Level::Absent => {}
                Level::Hi => {
                    let (start, end) = self.grid.owned_voxels(b);
                    for z in start.z..end.z {
                        for y in start.y..end.y {
                            for x in start.x..end.x {
                                let p = UVec3::new(x, y, z).as_vec3() + 0.5;
                                let expected = quantize_to(&[self.volume.value(x, y, z)], storage);
                                assert_eq!(self.image.texel(map(p)), &expected[..], "hi {i} {p}");
                            }
                        }
                    }
                }
                Level::Lo => {
                    let first = b.as_ivec3() * n / 2;
                    let last = (first + IVec3::splat(n / 2)).min(kmax);
                    for z in first.z..=last.z {
                        for y in first.y..=last.y {
                            for x in first.x..=last.x {
                                let k = IVec3::new(x, y, z);
                                let p = (k * 2).as_vec3();
                                let expected = quantize_to(&[self.level.value(k)], storage);
                                assert_eq!(self.image.texel(map(p)), &expected[..], "lo {i} {k}");
                            }
                        }
                    }
                }
            }
        }
    }

    fn count(&self, level: Level) -> usize {
        self.levels.iter().filter(|&&l| l == level).count()
    }
}

fn orbit(camera: &Camera, degrees: f32) -> Camera {
    let mut c = *camera;
    c.eye = glam::Quat::from_rotation_y(degrees.to_radians()) * (c.eye - c.target) + c.target;
    c
}

#[test]
fn one_voxel_thick_volume_end_to_end() {
    // 40 x 33 x 1, u8; the left third is zero, so its bricks are culled.
    let volume = volume(UVec3::new(40, 33, 1), ScalarType::U8, 1, |p, r| {
        if p.x < 14 {
            0.0
        } else {
            0.1 + 0.9 * r
        }
    });
    for filter in DownsampleFilter::ALL {
        let mut p = Pipeline::new(volume.clone(), 4, filter, ScalarType::U8, 1 << 20, None);
        assert_eq!(p.grid.bricks_per_axis(), UVec3::new(10, 9, 1));
        let culled = p.active.iter().filter(|&&a| !a).count();
        assert!(culled >= 2 * 9, "{filter:?}: only {culled} bricks culled");
        assert!(p.active.iter().any(|&a| a));
        let camera = Camera::perspective(Vec3::new(0.2, 0.3, 1.4), Vec3::ZERO, 40.0);
        let first = p.frame(&camera);
        assert_eq!(first.uploads.len(), p.active.iter().filter(|&&a| a).count());
        // Enough room for everything: every active brick hi-res.
        assert_eq!(p.count(Level::Lo), 0, "{filter:?}");
        // Same view again: nothing to do.
        assert!(p.frame(&camera).is_empty());
    }
    // 12 slots for 72 active bricks: at most three hi-res; stored in u16 from u8 voxels.
    let mut p = Pipeline::new(
        volume,
        4,
        DownsampleFilter::Box4,
        ScalarType::U16,
        1 << 20,
        Some(12),
    );
    let camera = Camera::perspective(Vec3::new(0.0, 0.0, 1.2), Vec3::ZERO, 40.0);
    p.frame(&camera);
    assert_eq!((p.count(Level::Hi), p.count(Level::Lo)), (3, 69));
    p.frame(&orbit(&camera, 20.0));
}

#[test]
fn prime_dimensions_end_to_end() {
    // 67 x 41 x 29 (all prime), u16 with an empty corner; 9 x 6 x 4 bricks of 8, partial on
    // every far face.
    let volume = volume(UVec3::new(67, 41, 29), ScalarType::U16, 2, |p, r| {
        if p.x + p.y < 30 {
            0.0
        } else {
            0.05 + 0.5 * r + 0.004 * p.z as f32
        }
    });
    let mut p = Pipeline::new(
        volume,
        8,
        DownsampleFilter::BSpline4,
        ScalarType::U16,
        1 << 22,
        Some(120),
    );
    assert_eq!(p.grid.bricks_per_axis(), UVec3::new(9, 6, 4));
    assert!(p.active.iter().any(|&a| !a), "the empty corner is culled");
    let mut camera = Camera::perspective(Vec3::new(0.9, 0.5, 1.3), Vec3::ZERO, 35.0);
    p.frame(&camera);
    assert!(
        p.count(Level::Lo) > 0,
        "120 slots cannot hold every brick hi-res"
    );
    for step in 0..6 {
        camera = orbit(&camera, 7.0);
        camera.eye *= 0.97;
        let update = p.frame(&camera);
        assert!(update.uploads.len() < p.grid.brick_count(), "step {step}");
    }
}

#[test]
fn bricks_beyond_the_cache_are_demoted_by_screen_space_error() {
    // 96 x 80 x 72 f32 (1080 bricks of 8) into a 256 KiB u8 cache: about 220 slots, a fifth of
    // the brick count, so most bricks must be low-res.
    let volume = volume(UVec3::new(96, 80, 72), ScalarType::F32, 3, |p, r| {
        0.2 + 0.3 * r * (p.x as f32 / 96.0) + 0.2 * (p.z as f32 / 72.0)
    });
    let mut p = Pipeline::new(
        volume,
        8,
        DownsampleFilter::Mean2,
        ScalarType::U8,
        64 * 64 * 64,
        None,
    );
    let slots = p.cache.capacity() as usize;
    assert_eq!(p.grid.brick_count(), 1080);
    assert!(4 * slots < 1080, "{slots} slots");
    assert!(p.active.iter().all(|&a| a));
    let mut camera = Camera::perspective(Vec3::new(0.3, 0.4, 1.1), Vec3::new(0.1, 0.0, 0.0), 50.0);
    for step in 0..4 {
        p.frame(&camera);
        let (hi, lo) = (p.count(Level::Hi), p.count(Level::Lo));
        assert_eq!(hi + lo, 1080);
        assert!(slots_needed(hi, lo) <= slots);
        // The budget is used: one more hi-res brick would not fit.
        assert!(
            slots_needed(hi + 1, lo - 1) > slots,
            "step {step}: {hi} hi, {lo} lo"
        );
        assert!(hi > 0 && lo > 900, "step {step}: {hi} hi, {lo} lo");
        // Higher screen-space error wins: every hi-res brick beats every low-res one.
        let view = Pipeline::view(&camera);
        let error = |i: usize| {
            let (min, max) = p.geometry.brick_box(p.grid.brick_coords(i));
            screen_space_error(&p.geometry, &view, min, max, p.store.value_ranges()[i])
        };
        let min_hi = (0..1080)
            .filter(|&i| p.levels[i] == Level::Hi)
            .map(error)
            .fold(f32::INFINITY, f32::min);
        let max_lo = (0..1080)
            .filter(|&i| p.levels[i] == Level::Lo)
            .map(error)
            .fold(0.0, f32::max);
        assert!(min_hi >= max_lo, "step {step}: hi {min_hi} < lo {max_lo}");
        assert!(min_hi > 0.0);
        camera = orbit(&camera, 3.0);
        camera.eye *= 0.98;
    }
    // Jump far away: the ranking changes a lot, yet the count rule keeps holding.
    let far = Camera::perspective(Vec3::new(-2.0, -1.0, -2.5), Vec3::ZERO, 30.0);
    let update = p.frame(&far);
    assert!(update.tables_changed);
    assert!(!update.uploads.is_empty());
}

#[test]
fn a_budget_below_all_low_res_is_a_typed_error() {
    let volume = volume(UVec3::new(96, 80, 72), ScalarType::U8, 4, |_, r| {
        0.1 + 0.8 * r
    });
    let mut p = Pipeline::new(
        volume,
        8,
        DownsampleFilter::Mean2,
        ScalarType::U8,
        1 << 22,
        None,
    );
    let active = p.active.iter().filter(|&&a| a).count();
    assert_eq!(active, 1080);
    let needed = active.div_ceil(8);
    let view = Pipeline::view(&Camera::default_view());
    // The selector refuses: all-low-res needs 135 slots.
    for slots in [0, 1, needed - 1] {
        let options = SelectionOptions::with_slots(slots);
        let result = p.selector.select_into(
            &p.geometry,
            &view,
            p.store.value_ranges(),
            &p.active,
            &options,
            &mut p.levels,
        );
        assert_eq!(
            result,
            Err(LodError::BudgetTooSmall {
                active,
                needed,
                slots
            })
        );
        let message = result.unwrap_err().to_string();
        assert!(message.contains("budget too small"), "{message}");
        assert!(message.contains(&needed.to_string()), "{message}");
    }
    // Exactly enough slots: everything low-res.
    let options = SelectionOptions::with_slots(needed);
    let summary = p
        .selector
        .select_into(
            &p.geometry,
            &view,
            p.store.value_ranges(),
            &p.active,
            &options,
            &mut p.levels,
        )
        .unwrap();
    assert_eq!((summary.hi, summary.lo), (0, active));
    // The cache refuses a plan over its capacity and stays unchanged.
    let mut small = BrickCache::with_slot_limit(p.grid, *p.cache.geometry(), 100).unwrap();
    let all_lo = vec![Level::Lo; p.grid.brick_count()];
    assert_eq!(
        small.update(&all_lo),
        Err(CacheError::OverBudget {
            hi: 0,
            lo: 1080,
            slots: 100
        })
    );
    assert!(small.levels().iter().all(|&l| l == Level::Absent));
    // A byte budget below a single slot is an error too.
    assert!(matches!(
        CacheGeometry::choose(8, 1, 500, 2048, 10),
        Err(CacheError::BudgetBelowOneSlot { .. })
    ));
}
