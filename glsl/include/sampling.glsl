// Reconstruction of the scalar field. Mirrors src/reference/sampling.rs.
#ifndef SAMPLING_GLSL
#define SAMPLING_GLSL

// Trilinear sample of the volume at normalised texture coordinate `tex` ([0,1]^3 spans the
// volume; voxel centres sit at (i + 0.5) / dims), clamp-to-edge outside.
float sample_volume(sampler3D volume, vec3 tex) {
    return texture(volume, tex).r;
}

#endif
