//! Definitions the Rust side and the GLSL side share, defined once here.
//!
//! - **Numbers** (descriptor bindings, workgroup sizes, array limits, loop counts) are Rust
//!   constants; [`defines`] turns them into GLSL macros, which [`super::shaders::compile`] adds to
//!   every compile of the crate's shaders, so the GLSL names them (`BINDING_VOLUME`,
//!   `MAX_CLIP_PLANES`, ...) and never writes the number by hand. Some live with the code they
//!   belong to and are only referenced here: the clip-plane limit
//!   ([`crate::scene::MAX_CLIP_PLANES`]), the iso bisection count
//!   ([`crate::scene::ISO_BISECTIONS`]), the words of a reverse-table entry
//!   ([`crate::bricks::SUB_SLOTS_PER_SLOT`]), the transfer-function table size
//!   ([`crate::optics::TF_SIZE`]) and the ray-direction epsilon
//!   ([`crate::scene::RAY_DIR_EPSILON`]).
//! - **Blocks** the shaders read (the uniform parameter block [`crate::scene::RaycastParams`],
//!   the push constants of `fixup.comp` and `probe.comp`) have their size and every field's
//!   offset checked at compile time below; each is mirrored by one GLSL declaration (named in its
//!   doc comment).

use crate::scene::RaycastParams;
use std::mem::{offset_of, size_of};

// ---- ray-cast (raycast.frag): descriptor set 0 ----

/// Ray-cast binding: the uniform parameter block (`RaycastParams`).
pub const BINDING_PARAMS: u32 = 0;
/// Ray-cast binding: the plain volume texture, or the brick cache (mixed resolution).
pub const BINDING_VOLUME: u32 = 1;
/// Ray-cast binding: the classification (transfer-function) table.
pub const BINDING_TF: u32 = 2;
/// Ray-cast binding: the brick layout table (mixed resolution).
pub const BINDING_LAYOUT_TABLE: u32 = 3;
/// Ray-cast binding: the brick neighbour bits (mixed resolution).
pub const BINDING_NEIGHBOUR_TABLE: u32 = 4;
/// Ray-cast binding: the host's depth buffer (host depth).
pub const BINDING_HOST_DEPTH: u32 = 5;
/// Ray-cast binding: the 2D pre-integration table (pre-integrated classification).
pub const BINDING_PREINTEGRATION: u32 = 6;

// ---- border fixup (fixup.comp): descriptor set 0 ----

/// Fixup binding: the brick cache as a storage image.
pub const FIXUP_BINDING_CACHE: u32 = 0;
/// Fixup binding: the brick layout table.
pub const FIXUP_BINDING_LAYOUT_TABLE: u32 = 1;
/// Fixup binding: the brick neighbour bits.
pub const FIXUP_BINDING_NEIGHBOUR_TABLE: u32 = 2;
/// Fixup binding: the reverse table (cache slot to brick).
pub const FIXUP_BINDING_REVERSE_TABLE: u32 = 3;
/// Fixup binding: the job list (cache slots to fix).
pub const FIXUP_BINDING_JOBS: u32 = 4;
/// Fixup workgroup edge: `FIXUP_GROUP_SIZE` x `FIXUP_GROUP_SIZE` texels of one brick face.
pub const FIXUP_GROUP_SIZE: u32 = 8;
/// Workgroup layers per fixup job (one per brick face): the z group index is
/// `job * FIXUP_FACES_PER_JOB + face`.
pub const FIXUP_FACES_PER_JOB: u32 = 6;

// ---- field probe (probe.comp): descriptor set 0 ----

/// Probe binding: the brick cache, sampled.
pub const PROBE_BINDING_CACHE: u32 = 0;
/// Probe binding: the brick layout table.
pub const PROBE_BINDING_LAYOUT_TABLE: u32 = 1;
/// Probe binding: the brick neighbour bits.
pub const PROBE_BINDING_NEIGHBOUR_TABLE: u32 = 2;
/// Probe binding: the points to sample.
pub const PROBE_BINDING_POINTS: u32 = 3;
/// Probe binding: the sampled values.
pub const PROBE_BINDING_VALUES: u32 = 4;
/// Probe workgroup size (points per group).
pub const PROBE_GROUP_SIZE: u32 = 64;

/// Every shared constant as a GLSL macro (name, value). [`super::shaders::compile`] adds these to
/// every compile of an embedded shader; hosts compiling their own GLSL against the crate's
/// include files with [`super::shaders::compile_source`] pass them too.
pub fn defines() -> Vec<(&'static str, String)> {
    let mut defines = vec![
        ("TF_SIZE", crate::optics::TF_SIZE.to_string()),
        (
            "RAY_DIR_EPSILON",
            format!("{:e}", crate::scene::RAY_DIR_EPSILON),
        ),
        ("MAX_CLIP_PLANES", crate::scene::MAX_CLIP_PLANES.to_string()),
        ("ISO_BISECTIONS", crate::scene::ISO_BISECTIONS.to_string()),
        (
            "SUB_SLOTS_PER_SLOT",
            crate::bricks::SUB_SLOTS_PER_SLOT.to_string(),
        ),
    ];
    for (name, value) in [
        ("BINDING_PARAMS", BINDING_PARAMS),
        ("BINDING_VOLUME", BINDING_VOLUME),
        ("BINDING_TF", BINDING_TF),
        ("BINDING_LAYOUT_TABLE", BINDING_LAYOUT_TABLE),
        ("BINDING_NEIGHBOUR_TABLE", BINDING_NEIGHBOUR_TABLE),
        ("BINDING_HOST_DEPTH", BINDING_HOST_DEPTH),
        ("BINDING_PREINTEGRATION", BINDING_PREINTEGRATION),
        ("FIXUP_BINDING_CACHE", FIXUP_BINDING_CACHE),
        ("FIXUP_BINDING_LAYOUT_TABLE", FIXUP_BINDING_LAYOUT_TABLE),
        (
            "FIXUP_BINDING_NEIGHBOUR_TABLE",
            FIXUP_BINDING_NEIGHBOUR_TABLE,
        ),
        ("FIXUP_BINDING_REVERSE_TABLE", FIXUP_BINDING_REVERSE_TABLE),
        ("FIXUP_BINDING_JOBS", FIXUP_BINDING_JOBS),
        ("FIXUP_GROUP_SIZE", FIXUP_GROUP_SIZE),
        ("FIXUP_FACES_PER_JOB", FIXUP_FACES_PER_JOB),
        ("PROBE_BINDING_CACHE", PROBE_BINDING_CACHE),
        ("PROBE_BINDING_LAYOUT_TABLE", PROBE_BINDING_LAYOUT_TABLE),
        (
            "PROBE_BINDING_NEIGHBOUR_TABLE",
            PROBE_BINDING_NEIGHBOUR_TABLE,
        ),
        ("PROBE_BINDING_POINTS", PROBE_BINDING_POINTS),
        ("PROBE_BINDING_VALUES", PROBE_BINDING_VALUES),
        ("PROBE_GROUP_SIZE", PROBE_GROUP_SIZE),
    ] {
        defines.push((name, value.to_string()));
    }
    defines
}

// ---- blocks ----

/// Push constants of `fixup.comp`: mirrors `FixupParams` there.
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FixupPush {
    /// xyz: bricks per axis; w: brick size n.
    pub(crate) bricks: [i32; 4],
    /// xyz: cache slots per axis; w: number of jobs.
    pub(crate) slots_per_axis: [i32; 4],
}

const _: () = assert!(size_of::<FixupPush>() == 32);
const _: () = assert!(offset_of!(FixupPush, bricks) == 0);
const _: () = assert!(offset_of!(FixupPush, slots_per_axis) == 16);

/// Push constants of `probe.comp`: mirrors `ProbeParams` there.
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ProbePush {
    /// xyz: volume dimensions; w: brick size n.
    pub(crate) volume_dims: [f32; 4],
    /// xyz: 1 / cache extent in texels; w: number of points.
    pub(crate) cache_extent_inv: [f32; 4],
}

const _: () = assert!(size_of::<ProbePush>() == 32);
const _: () = assert!(offset_of!(ProbePush, volume_dims) == 0);
const _: () = assert!(offset_of!(ProbePush, cache_extent_inv) == 16);

// `RaycastParams` (src/scene.rs) mirrors `RaycastParams` in glsl/include/params.glsl (std140:
// vec4s, an array of MAX_CLIP_PLANES vec4s, one mat4).
const _: () = assert!(size_of::<RaycastParams>() == 368);
const _: () = assert!(offset_of!(RaycastParams, eye) == 0);
const _: () = assert!(offset_of!(RaycastParams, forward) == 16);
const _: () = assert!(offset_of!(RaycastParams, right) == 32);
const _: () = assert!(offset_of!(RaycastParams, up) == 48);
const _: () = assert!(offset_of!(RaycastParams, box_min) == 64);
const _: () = assert!(offset_of!(RaycastParams, box_max) == 80);
const _: () = assert!(offset_of!(RaycastParams, tf_window) == 96);
const _: () = assert!(offset_of!(RaycastParams, viewport) == 112);
const _: () = assert!(offset_of!(RaycastParams, volume_dims) == 128);
const _: () = assert!(offset_of!(RaycastParams, cache_extent_inv) == 144);
const _: () = assert!(offset_of!(RaycastParams, mode) == 160);
const _: () = assert!(offset_of!(RaycastParams, shading) == 176);
const _: () = assert!(offset_of!(RaycastParams, iso_colour) == 192);
const _: () = assert!(offset_of!(RaycastParams, clip_planes) == 208);
// std140 array stride of vec4 is 16: the array holds MAX_CLIP_PLANES of them back to back.
const _: () =
    assert!(offset_of!(RaycastParams, world_from_clip) == 208 + 16 * crate::scene::MAX_CLIP_PLANES);
const _: () = assert!(offset_of!(RaycastParams, world_from_clip) == 304);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::shaders::embedded_sources;
    use std::collections::HashSet;

    /// The identifiers (maximal runs of `[A-Za-z0-9_]` not starting with a digit) of `text`.
    fn tokens(text: &str) -> impl Iterator<Item = &str> {
        text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .filter(|t| t.chars().next().is_some_and(|c| !c.is_ascii_digit()))
    }

    /// Whether `token` names something of the shared kind (a binding, a limit, a group size).
    fn looks_shared(token: &str) -> bool {
        token.contains("BINDING")
            || token.starts_with("MAX_")
            || token.ends_with("_GROUP_SIZE")
            || token.ends_with("_PER_JOB")
            || token.ends_with("_PER_SLOT")
            || token.ends_with("BISECTIONS")
    }

    #[test]
    fn every_shared_name_a_shader_uses_is_defined_once_in_rust() {
        let defines = defines();
        let names: HashSet<&str> = defines.iter().map(|(n, _)| *n).collect();
        assert_eq!(names.len(), defines.len(), "a macro is listed twice");
        let mut used = HashSet::new();
        for (path, text) in embedded_sources() {
            for token in tokens(text) {
                if names.contains(token) {
                    used.insert(token);
                } else {
                    assert!(
                        !looks_shared(token),
                        "{path} uses {token}, which shared_defs::defines() does not define"
                    );
                }
            }
            for line in text.lines() {
                let code = line.split("//").next().unwrap_or_default();
                // No shared name is (re)defined in GLSL.
                if let Some(rest) = code.trim_start().strip_prefix("#define") {
                    let name = rest.split_whitespace().next().unwrap_or_default();
                    assert!(!names.contains(name), "{path} defines {name} itself");
                }
                // No binding number is written by hand.
                if let Some((_, rest)) = code.split_once("binding") {
                    let value = rest.trim_start().trim_start_matches('=').trim_start();
                    assert!(
                        !value.starts_with(|c: char| c.is_ascii_digit()),
                        "{path}: hand-written binding number in `{line}`"
                    );
                }
                // Arrays are sized by shared names, not numbers (clip planes).
                assert!(
                    !code.contains("[6]"),
                    "{path}: hand-written array size in `{line}`"
                );
            }
        }
        for name in &names {
            assert!(used.contains(name), "no shader uses {name}");
        }
    }

    #[test]
    fn binding_numbers_are_distinct_within_each_shader() {
        let groups: [&[u32]; 3] = [
            &[
                BINDING_PARAMS,
                BINDING_VOLUME,
                BINDING_TF,
                BINDING_LAYOUT_TABLE,
                BINDING_NEIGHBOUR_TABLE,
                BINDING_HOST_DEPTH,
                BINDING_PREINTEGRATION,
            ],
            &[
                FIXUP_BINDING_CACHE,
                FIXUP_BINDING_LAYOUT_TABLE,
                FIXUP_BINDING_NEIGHBOUR_TABLE,
                FIXUP_BINDING_REVERSE_TABLE,
                FIXUP_BINDING_JOBS,
            ],
            &[
                PROBE_BINDING_CACHE,
                PROBE_BINDING_LAYOUT_TABLE,
                PROBE_BINDING_NEIGHBOUR_TABLE,
                PROBE_BINDING_POINTS,
                PROBE_BINDING_VALUES,
            ],
        ];
        for group in groups {
            let distinct: HashSet<_> = group.iter().collect();
            assert_eq!(distinct.len(), group.len(), "{group:?}");
        }
    }
}
