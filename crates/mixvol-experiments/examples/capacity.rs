//! Prints the capacity report (`mixvol_experiments::capacity`): texels per voxel for every level
//! of the two- and three-level schemes, and the largest volume a cache can draw.
//!
//! `cargo run --release -p mixvol-experiments --example capacity [CACHE_GIB [BYTES_PER_TEXEL
//! [MAX_DIM_3D]]]` (defaults 2 GiB, 1 byte, 16384 texels per axis). `docs/report/capacity.md`
//! holds its output for the defaults.

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: f64| -> f64 {
        match args.get(i) {
            None => default,
            Some(a) => a.parse().unwrap_or_else(|_| {
                eprintln!("capacity: argument {} ({a:?}) is not a number", i + 1);
                std::process::exit(2)
            }),
        }
    };
    let gib = arg(0, 2.0);
    let bytes_per_texel = arg(1, 1.0);
    let max_dim = arg(2, 16384.0);
    if !(gib > 0.0 && bytes_per_texel >= 1.0 && max_dim >= 1.0) {
        eprintln!("capacity: expected CACHE_GIB > 0, BYTES_PER_TEXEL >= 1, MAX_DIM_3D >= 1");
        std::process::exit(2);
    }
    let budget = (gib * f64::from(1u32 << 30)) as u64;
    print!(
        "{}",
        mixvol_experiments::capacity::report(bytes_per_texel as u32, budget, max_dim as u32)
    );
}
