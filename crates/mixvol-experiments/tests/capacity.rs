//! The capacity report's figures: the slot packings hold their bricks exactly, the slot search
//! finds what the library's cache layout finds, and the capacities follow.

use mixvol::cache::{CacheGeometry, SlotGeometry};
use mixvol_experiments::capacity::{capacity, level_costs, most_slots, Scheme};

#[test]
fn every_level_fills_its_slot_exactly() {
    // 2 (n/2 + 1) = n + 2 and 2 (n/2 + 2) = 4 (n/4 + 1) = n + 4: the sub-bricks tile the slot.
    for n in [8, 16, 32, 64, 128] {
        for scheme in Scheme::ALL {
            let slot = u64::from(scheme.slot_edge(n)).pow(3);
            for (edge, per_slot) in scheme.levels(n) {
                assert_eq!(
                    u64::from(edge).pow(3) * u64::from(per_slot),
                    slot,
                    "{scheme:?}, n = {n}, brick edge {edge}"
                );
            }
        }
    }
    // The figures for n = 32: 34^3 / 8 = 4913 texels at low resolution, 36^3 / 64 = 729
    // at level 2.
    let two = level_costs(Scheme::TwoLevel, 32);
    let three = level_costs(Scheme::ThreeLevel, 32);
    assert_eq!(two.len(), 2);
    assert_eq!(three.len(), 3);
    assert_eq!(two[0].texels_per_brick, 39304.0);
    assert_eq!(two[1].texels_per_brick, 4913.0);
    assert_eq!(three[0].texels_per_brick, 46656.0);
    assert_eq!(three[1].texels_per_brick, 5832.0);
    assert_eq!(three[2].texels_per_brick, 729.0);
    assert!((two[1].texels_per_voxel - 4913.0 / 32768.0).abs() < 1e-12);
}

#[test]
fn the_slot_search_finds_as_many_slots_as_the_cache_layout() {
    // `CacheGeometry::choose` and `SlotGeometry::choose` asked for more slots than fit
    // return the extent with the most slots: the same count (and texels) as `most_slots` for
    // their slot edges.
    for n in [8, 16, 32, 64] {
        for (budget, max_dim) in [
            (1u64 << 20, 2048),
            (48 << 20, 2048),
            (1 << 30, 2048),
            (3 << 30, 4096),
            (1 << 31, 16384),
        ] {
            for bytes_per_texel in [1, 2] {
                let two = CacheGeometry::choose(n, bytes_per_texel, budget, max_dim, u32::MAX)
                    .map(|g| (u64::from(g.slot_count()), g.texel_count()));
                let three = SlotGeometry::choose(n, 3, bytes_per_texel, budget, max_dim, u32::MAX)
                    .map(|g| {
                        (
                            u64::from(g.slot_count()),
                            g.extent().as_u64vec3().element_product(),
                        )
                    });
                for (scheme, geometry) in [(Scheme::TwoLevel, two), (Scheme::ThreeLevel, three)] {
                    let found = most_slots(scheme.slot_edge(n), bytes_per_texel, budget, max_dim);
                    match (geometry, found) {
                        (Ok((slot_count, texel_count)), Some((extent, slots))) => {
                            assert_eq!(slot_count, slots, "{scheme:?} n {n}, budget {budget}");
                            let texels: u64 = extent.iter().map(|&c| u64::from(c)).product();
                            assert_eq!(texel_count, texels, "{scheme:?} n {n}, budget {budget}");
                        }
                        (Err(_), None) => {}
                        (g, f) => {
                            panic!("{scheme:?} n {n}, budget {budget}: layout {g:?}, search {f:?}")
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn three_levels_draw_several_times_the_volume_of_two() {
    // A 2 GiB cache of u8 texels, bricks of 32: two levels draw at most 8 n^3 / (n+2)^3 = 6.67x
    // the cache's texels (less the slots' fit into power-of-two axes), three levels
    // 64 n^3 / (n+4)^3 = 44.9x.
    let budget = 2u64 << 30;
    let two = capacity(Scheme::TwoLevel, 32, 1, budget, 16384).unwrap();
    let three = capacity(Scheme::ThreeLevel, 32, 1, budget, 16384).unwrap();
    let over_cache = |voxels: u64| voxels as f64 / budget as f64;
    assert!(
        (6.0..=32768.0 * 8.0 / 39304.0).contains(&over_cache(two.voxels)),
        "{two:?}"
    );
    assert!(
        (40.0..=32768.0 * 64.0 / 46656.0).contains(&over_cache(three.voxels)),
        "{three:?}"
    );
    assert_eq!(two.bricks, two.slots * 8);
    assert_eq!(three.bricks, three.slots * 64);
    // No slot fits a budget below one power-of-two slot.
    assert!(capacity(Scheme::ThreeLevel, 32, 1, 63 * 63 * 63, 16384).is_none());
}

#[test]
fn each_block_level_costs_an_eighth_of_the_one_before() {
    // Past level 2 a stored brick keeps the level-2 size and covers twice the extent per axis.
    for n in [16, 32, 64] {
        let costs = level_costs(Scheme::Blocks, n);
        let three = level_costs(Scheme::ThreeLevel, n);
        assert_eq!(
            costs.len(),
            mixvol_experiments::capacity::BLOCK_LEVELS as usize
        );
        assert_eq!(&costs[..3], &three[..]);
        for k in 3..costs.len() {
            assert_eq!(costs[k].texels_per_brick, costs[2].texels_per_brick);
            let ratio = costs[k - 1].texels_per_voxel / costs[k].texels_per_voxel;
            assert!((ratio - 8.0).abs() < 1e-9, "n {n}, level {k}: {ratio}");
        }
        // The same slots, each stored brick standing for 8^3 bricks at level 5.
        let blocks = capacity(Scheme::Blocks, n, 1, 2 << 30, 16384).unwrap();
        let three = capacity(Scheme::ThreeLevel, n, 1, 2 << 30, 16384).unwrap();
        assert_eq!(blocks.slots, three.slots);
        assert_eq!(blocks.voxels, three.voxels * 512);
    }
}
