// Per-frame ray-casting parameters. Mirrors `RaycastParams` in src/scene.rs field by field
// (std140: vec4s and one mat4, 368 bytes; offsets checked in src/gpu/shared_defs.rs).
#ifndef PARAMS_GLSL
#define PARAMS_GLSL

struct RaycastParams {
    vec4 eye;       // xyz: eye (perspective) or image-plane centre (orthographic); w: 0 persp, 1 ortho
    vec4 forward;   // xyz: unit view direction; w: near (smallest ray parameter t)
    vec4 right;     // xyz: right vector scaled to half the image width at unit distance; w: far
    vec4 up;        // xyz: up vector scaled to half the image height at unit distance; w: unused
    vec4 box_min;   // xyz: world-space volume box minimum; w: step length (world units)
    vec4 box_max;   // xyz: world-space volume box maximum; w: reference length d0 (world units)
    vec4 tf_window; // x: value at TF position 0; y: 1 / (value range); z: early-termination alpha; w: max steps
    vec4 viewport;  // x: width, y: height (pixels); zw: unused
    vec4 volume_dims;      // xyz: volume dimensions in voxels; w: brick size n (mixed resolution)
    vec4 cache_extent_inv; // xyz: 1 / cache extent in texels (mixed resolution); w: unused
    vec4 mode;             // x: iso value; y: MIDA gamma; z: gradient opacity scale; w: gradient step (voxels)
    vec4 shading;          // x: ambient, y: diffuse, z: specular, w: shininess (Blinn-Phong)
    vec4 iso_colour;       // rgb: iso-surface colour; w: number of clip planes
    vec4 clip_planes[MAX_CLIP_PLANES]; // xyz: normal towards the kept side, w: offset
    mat4 world_from_clip;  // inverse of the host's clip_from_world (HOST_DEPTH only)
};

#endif
