//! What a ray computes from its samples: render modes, shading, gradient opacity, sampling
//! models and pre-integration. Mirrors `glsl/include/modes.glsl` function by function; where the
//! GLSL switches code on and off with variant macros, this reads [`RayFeatures`].

use super::sampling::sample_tricubic;
use crate::optics::preintegration::PreintegrationTable;
use crate::optics::{composite, correct_opacity, sample_colour, tf_position, ClassificationTable};
use crate::scene::{ModeKind, RayFeatures, RaycastParams, ISO_BISECTIONS};
use glam::{Vec3, Vec4};

/// Everything a ray's samples are interpreted with: the features (the GLSL variant), the
/// classification table (the TF texture), the optional pre-integration table and the
/// reconstructed field for gradients and iso refinement (`field_at` in GLSL: `None` in an absent
/// brick).
pub struct RayProgram<'a> {
    /// The effects compiled in.
    pub features: RayFeatures,
    /// The transfer function as the GPU texture holds it.
    pub table: &'a ClassificationTable,
    /// The 2D table (required when `features.preintegrated`).
    pub preintegration: Option<&'a PreintegrationTable>,
    /// The per-frame parameter block.
    pub params: &'a RaycastParams,
    /// The trilinearly reconstructed field at a voxel position (`field_at` in GLSL).
    pub field: &'a dyn Fn(Vec3) -> Option<f32>,
}

/// A ray's running state. Mirrors `RayState`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RayState {
    /// Premultiplied colour and opacity so far.
    pub acc: Vec4,
    /// MIP, MIDA: largest TF position so far (-1: none yet).
    pub max_pos: f32,
    /// ISO, pre-integration: the previous sample's value.
    pub prev_value: f32,
    /// Pre-integration: the length the previous sample stands for (world units); half of it
    /// lies behind the sample, the closing segment of a run ([`RayProgram::break_ray`]).
    pub prev_len: f32,
    /// Pre-integration with shading or gradient opacity: the previous sample's gradient.
    pub prev_gradient: Vec3,
    /// ISO: the previous sample's position (voxels).
    pub prev_x: Vec3,
    /// Whether `prev_*` hold a sample (false after a gap).
    pub has_prev: bool,
    /// ISO: the ray crossed the iso value between `prev_x` and `hit_x`.
    pub hit: bool,
    /// ISO: the first sample past the crossing.
    pub hit_x: Vec3,
    /// ISO: its value.
    pub hit_value: f32,
}

impl Default for RayState {
    fn default() -> Self {
        Self {
            acc: Vec4::ZERO,
            max_pos: -1.0,
            prev_value: 0.0,
            prev_len: 0.0,
            prev_gradient: Vec3::ZERO,
            prev_x: Vec3::ZERO,
            has_prev: false,
            hit: false,
            hit_x: Vec3::ZERO,
            hit_value: 0.0,
        }
    }
}

impl RayProgram<'_> {
    /// The field the samples, gradients and iso refinement see: `field`, or with
    /// `features.tricubic` its cubic B-spline. Mirrors `field_value` in raycast.frag.
    pub fn field_value(&self, x: Vec3) -> Option<f32> {
        if self.features.tricubic {
            Some(sample_tricubic(self.field, x))
        } else {
            (self.field)(x)
        }
    }

    /// The ray interval cut by the clip planes when the program has them (`CLIP_PLANES`).
    pub fn clipped(&self, ray: &super::Ray, t0: f32, t1: f32) -> (f32, f32) {
        if self.features.clip_planes {
            let count = self.params.iso_colour.w as usize;
            super::clip_ray(ray, t0, t1, &self.params.clip_planes[..count])
        } else {
            (t0, t1)
        }
    }

    /// A gap in the samples (an absent brick): closes the pre-integrated run
    /// ([`Self::close_run`]) and forgets the previous sample. Mirrors `break_ray`.
    pub fn break_ray(&self, s: &mut RayState, view_dir: Vec3) {
        self.close_run(s, view_dir);
        s.has_prev = false;
    }

    /// Pre-integration (DVR, MIDA): composites the part of the run behind its last sample, half
    /// the length that sample stands for, at the sample's constant classification. Samples lie
    /// at the middles of their steps and pre-integrated segments join neighbouring samples, so
    /// a run of samples is covered by a half step in front of its first sample (a constant
    /// segment, [`Self::integrate_sample`]), the segments between samples and this half step
    /// behind its last. No-op otherwise. Mirrors `close_run`.
    pub fn close_run(&self, s: &mut RayState, view_dir: Vec3) {
        let f = self.features;
        if !(f.preintegrated && matches!(f.mode, ModeKind::Dvr | ModeKind::Mida) && s.has_prev) {
            return;
        }
        let p = self.params;
        let pos = tf_position(p.tf_window.x, p.tf_window.y, s.prev_value);
        let seg = self
            .preintegration
            .expect("a pre-integrated program carries its table")
            .lookup(pos, pos);
        let mut rgb = sample_colour(seg);
        let mut alpha = correct_opacity(seg.w, 0.5 * s.prev_len / p.box_min.w);
        if f.gradient_opacity {
            alpha *= self.gradient_opacity(s.prev_gradient);
        }
        if f.shading {
            rgb = self.shade(rgb, s.prev_gradient, view_dir);
        }
        // MIDA: the maximum already holds this position (beta = 1), so its blend is "over".
        s.acc = composite(s.acc, rgb, alpha);
        s.prev_len = 0.0;
    }

    /// World-space gradient at voxel position `x` (field value `value` there) by central
    /// differences; an absent side falls back to `x` itself. Mirrors `field_gradient`.
    pub fn field_gradient(&self, x: Vec3, value: f32) -> Vec3 {
        let p = self.params;
        let h = p.mode.w;
        let to_voxel = p.volume_dims.truncate() / (p.box_max.truncate() - p.box_min.truncate());
        let mut g = Vec3::ZERO;
        for k in 0..3 {
            let mut e = Vec3::ZERO;
            e[k] = h;
            let hi = self.field_value(x + e);
            let lo = self.field_value(x - e);
            let span = hi.map_or(0.0, |_| h) + lo.map_or(0.0, |_| h);
            let (hi, lo) = (hi.unwrap_or(value), lo.unwrap_or(value));
            g[k] = if span > 0.0 { (hi - lo) / span } else { 0.0 };
        }
        g * to_voxel
    }

    /// Blinn-Phong with a headlight, two-sided. Mirrors `shade`.
    pub fn shade(&self, rgb: Vec3, gradient: Vec3, view_dir: Vec3) -> Vec3 {
        let sh = self.params.shading;
        let len = gradient.length();
        let n_dot_l = if len > 0.0 {
            (gradient.dot(view_dir).abs() / len).min(1.0)
        } else {
            1.0
        };
        rgb * (sh.x + sh.y * n_dot_l) + Vec3::splat(sh.z * n_dot_l.powf(sh.w))
    }

    /// Opacity scale from the gradient magnitude. Mirrors `gradient_opacity`.
    pub fn gradient_opacity(&self, gradient: Vec3) -> f32 {
        let p = self.params;
        (p.mode.z * gradient.length() * p.tf_window.y.abs()).min(1.0)
    }

    /// The transfer function at the largest TF position. Mirrors `mip_colour`.
    pub fn mip_colour(&self, max_pos: f32) -> Vec4 {
        if max_pos < 0.0 {
            return Vec4::ZERO;
        }
        let w = self.table.lookup(max_pos);
        let alpha = self.table.reference_opacity(w.w);
        (sample_colour(w) * alpha).extend(alpha)
    }

    /// Iso-surface point between `a` and `b`. Mirrors `refine_iso`.
    pub fn refine_iso(&self, mut a: Vec3, mut fa: f32, mut b: Vec3, mut fb: f32) -> Vec3 {
        let iso = self.params.mode.x;
        let a_below = fa < iso;
        for _ in 0..ISO_BISECTIONS {
            let m = 0.5 * (a + b);
            let fm = self.field_value(m).unwrap_or(0.0);
            if (fm < iso) == a_below {
                a = m;
                fa = fm;
            } else {
                b = m;
                fb = fm;
            }
        }
        let denom = fb - fa;
        let t = if denom != 0.0 {
            ((iso - fa) / denom).clamp(0.0, 1.0)
        } else {
            0.5
        };
        a * (1.0 - t) + b * t
    }

    /// Colour and opacity of one sample before gradient effects. Mirrors `classify_sample`.
    fn classify_sample(&self, s: &mut RayState, value: f32, len: f32) -> Vec4 {
        let p = self.params;
        let pos = tf_position(p.tf_window.x, p.tf_window.y, value);
        if self.features.preintegrated {
            // The segment from the previous sample (half of each one's length), or from the
            // run's start half a step in front (constant).
            let (front, seg_len) = if s.has_prev {
                (
                    tf_position(p.tf_window.x, p.tf_window.y, s.prev_value),
                    0.5 * (s.prev_len + len),
                )
            } else {
                (pos, 0.5 * len)
            };
            s.prev_value = value;
            s.prev_len = len;
            s.has_prev = true;
            let seg = self
                .preintegration
                .expect("a pre-integrated program carries its table")
                .lookup(front, pos);
            sample_colour(seg).extend(correct_opacity(seg.w, seg_len / p.box_min.w))
        } else {
            let w = self.table.lookup(pos);
            sample_colour(w).extend(self.table.sample_opacity(w.w, len / p.box_max.w))
        }
    }

    /// Adds one sample to the ray; true once nothing further can change the result. Mirrors
    /// `integrate_sample`.
    pub fn integrate_sample(
        &self,
        s: &mut RayState,
        value: f32,
        len: f32,
        x: Vec3,
        view_dir: Vec3,
    ) -> bool {
        let p = self.params;
        let f = self.features;
        match f.mode {
            ModeKind::Iso => {
                let iso = p.mode.x;
                if s.has_prev && ((s.prev_value < iso) != (value < iso)) {
                    s.hit = true;
                    s.hit_x = x;
                    s.hit_value = value;
                    return true;
                }
                s.prev_value = value;
                s.prev_x = x;
                s.has_prev = true;
                false
            }
            ModeKind::Mip => {
                s.max_pos = s
                    .max_pos
                    .max(tf_position(p.tf_window.x, p.tf_window.y, value));
                s.max_pos >= 1.0
            }
            ModeKind::Dvr | ModeKind::Mida => {
                let sample = self.classify_sample(s, value, len);
                let mut rgb = sample.truncate();
                let mut alpha = sample.w;
                if f.shading || f.gradient_opacity {
                    let g = self.field_gradient(x, value);
                    if f.preintegrated {
                        s.prev_gradient = g;
                    }
                    if f.gradient_opacity {
                        alpha *= self.gradient_opacity(g);
                    }
                    if f.shading {
                        rgb = self.shade(rgb, g, view_dir);
                    }
                }
                if f.mode == ModeKind::Mida {
                    let pos = tf_position(p.tf_window.x, p.tf_window.y, value);
                    let gamma = p.mode.y;
                    let delta = (pos - s.max_pos.max(0.0)).max(0.0);
                    let beta = 1.0 - delta * (1.0 + gamma.min(0.0));
                    let weight = (1.0 - beta * s.acc.w) * alpha;
                    s.acc =
                        (beta * s.acc.truncate() + weight * rgb).extend(beta * s.acc.w + weight);
                    s.max_pos = s.max_pos.max(pos);
                    s.acc.w >= p.tf_window.z && (s.max_pos >= 1.0 || gamma <= -1.0)
                } else {
                    s.acc = composite(s.acc, rgb, alpha);
                    s.acc.w >= p.tf_window.z
                }
            }
        }
    }

    /// Adds a pre-classified sample (weighted colour, coefficient) standing for a segment `len`
    /// world units long; true once the ray is opaque enough to stop. Mirrors `integrate_weighted`.
    pub fn integrate_weighted(&self, s: &mut RayState, weighted: Vec4, len: f32) -> bool {
        let p = self.params;
        let alpha = self.table.sample_opacity(weighted.w, len / p.box_max.w);
        s.acc = composite(s.acc, sample_colour(weighted), alpha);
        s.acc.w >= p.tf_window.z
    }

    /// The ray's result (after closing a pre-integrated run, [`Self::close_run`]). Mirrors
    /// `finish_ray`.
    pub fn finish_ray(&self, s: &RayState, view_dir: Vec3) -> Vec4 {
        let mut closed = *s;
        self.close_run(&mut closed, view_dir);
        let s = &closed;
        match self.features.mode {
            ModeKind::Iso => {
                if !s.hit {
                    return Vec4::ZERO;
                }
                let hit = self.refine_iso(s.prev_x, s.prev_value, s.hit_x, s.hit_value);
                let mut rgb = self.params.iso_colour.truncate();
                if self.features.shading {
                    let at_hit = self.field_value(hit).unwrap_or(0.0);
                    rgb = self.shade(rgb, self.field_gradient(hit, at_hit), view_dir);
                }
                rgb.extend(1.0)
            }
            ModeKind::Mip => self.mip_colour(s.max_pos),
            ModeKind::Mida => {
                let gamma = self.params.mode.y;
                if gamma > 0.0 {
                    s.acc * (1.0 - gamma) + self.mip_colour(s.max_pos) * gamma
                } else {
                    s.acc
                }
            }
            _ => s.acc,
        }
    }
}
