//! Camera paths for `render` and `bench`: one view, a turntable orbit (`--orbit N`), a dolly
//! towards the target (`--dolly N`), or keyframes from a JSON file (`--path FILE.json`),
//! interpolated.
//!
//! The keyframe file:
//! ```json
//! { "frames": 60,
//!   "keyframes": [
//!     { "eye": [1.0, 1.3, 1.4], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 35 },
//!     { "eye": [0.3, 0.4, 0.5] } ] }
//! ```
//! `frames` (optional, default: one per keyframe) frames are spread evenly over the path from
//! the first keyframe to the last; between two keyframes eye, target and up are interpolated
//! linearly (up renormalised) and so is the field of view. A keyframe's missing `target`, `up`
//! or `fov` is the previous keyframe's (the first takes `--target`, `--up`, `--fov`).

use glam::{Quat, Vec3};
use mixvol::scene::{Camera, Projection};
use mixvol::{Error, Result};
use serde::Deserialize;
use std::path::Path;

/// Most frames a path may have (a typo like `--orbit 1000000000` is refused before any work).
pub const MAX_PATH_FRAMES: u32 = 100_000;

/// One keyframe as the file holds it.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct KeyframeJson {
    eye: [f32; 3],
    target: Option<[f32; 3]>,
    up: Option<[f32; 3]>,
    fov: Option<f32>,
}

/// The keyframe file.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct PathJson {
    frames: Option<u32>,
    keyframes: Vec<KeyframeJson>,
}

/// A keyframe with every field filled.
#[derive(Copy, Clone, Debug, PartialEq)]
struct Keyframe {
    eye: Vec3,
    target: Vec3,
    up: Vec3,
    fov: f32,
}

/// Checks a frame count given by `flag` (`--orbit`, `--frames`, ...): 1 to [`MAX_PATH_FRAMES`],
/// so that a typo is refused before any work instead of rendering for hours.
pub fn check_frames(flag: &str, frames: u32) -> Result<()> {
    if frames == 0 || frames > MAX_PATH_FRAMES {
        return Err(Error::InvalidInput(format!(
            "{flag} {frames}: expected 1 to {MAX_PATH_FRAMES} frames"
        )));
    }
    Ok(())
}

/// A turntable of `frames` views around `base.target` about `base.up`, starting at `base.eye`
/// (one full turn; frame `i` at `360 i / frames` degrees). With `elevation_degrees` the eye is
/// moved to that elevation above the plane through the target normal to up, at the same
/// distance.
pub fn orbit(base: &Camera, frames: u32, elevation_degrees: Option<f32>) -> Result<Vec<Camera>> {
    check_frames("--orbit", frames)?;
    let up = base.up.normalize_or_zero();
    let offset = base.eye - base.target;
    if up == Vec3::ZERO || offset.length() == 0.0 || !offset.is_finite() {
        return Err(Error::InvalidInput(
            "--orbit needs an eye away from the target and a non-zero --up".into(),
        ));
    }
    let offset = match elevation_degrees {
        None => offset,
        Some(e) if e.is_finite() && e.abs() < 90.0 => {
            let planar = offset - up * offset.dot(up);
            let planar = if planar.length() > 1e-6 {
                planar.normalize()
            } else {
                up.any_orthonormal_vector()
            };
            let e = e.to_radians();
            (planar * e.cos() + up * e.sin()) * offset.length()
        }
        Some(e) => {
            return Err(Error::InvalidInput(format!(
                "--elevation {e}: expected degrees strictly between -90 and 90"
            )))
        }
    };
    Ok((0..frames)
        .map(|i| {
            let angle = std::f32::consts::TAU * i as f32 / frames as f32;
            Camera {
                eye: base.target + Quat::from_axis_angle(up, angle) * offset,
                ..*base
            }
        })
        .collect())
}

/// `frames` views moving the eye from `base.eye` straight towards `base.target`, ending at
/// `end_fraction` of the starting distance (frame 0 at the start, the last at the end).
pub fn dolly(base: &Camera, frames: u32, end_fraction: f32) -> Result<Vec<Camera>> {
    check_frames("--dolly", frames)?;
    if !(end_fraction > 0.0 && end_fraction <= 1.0) {
        return Err(Error::InvalidInput(format!(
            "dolly end fraction {end_fraction}: expected (0, 1]"
        )));
    }
    Ok((0..frames)
        .map(|i| {
            let t = if frames == 1 {
                0.0
            } else {
                i as f32 / (frames - 1) as f32
            };
            let f = 1.0 + (end_fraction - 1.0) * t;
            Camera {
                eye: base.target + (base.eye - base.target) * f,
                ..*base
            }
        })
        .collect())
}

/// The views of the keyframe file `path` (see the module docs); `base` gives the projection's
/// kind, near and far, and the first keyframe's defaults.
pub fn load_path(path: &Path, base: &Camera) -> Result<Vec<Camera>> {
    let what = |message: String| Error::InvalidInput(format!("{}: {message}", path.display()));
    // The file type first: reading a FIFO would block until a writer comes (review D10).
    let meta = std::fs::metadata(path).map_err(|e| what(format!("cannot read: {e}")))?;
    if !meta.is_file() {
        let kind = if meta.is_dir() {
            "a folder"
        } else {
            "a FIFO, device or socket"
        };
        return Err(what(format!(
            "not a regular file ({kind}); --path takes a camera path JSON file"
        )));
    }
    let text = std::fs::read_to_string(path).map_err(|e| what(format!("cannot read: {e}")))?;
    // The top level first (review D28: an array was "invalid length 1, expected struct
    // PathJson"): what the file must be, then serde's word on the fields.
    let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| what(e.to_string()))?;
    if !value.is_object() {
        return Err(what(
            "the path file must be a JSON object with \"keyframes\" (and optionally \"frames\")"
                .into(),
        ));
    }
    let json: PathJson = serde_json::from_value(value).map_err(|e| what(e.to_string()))?;
    if json.keyframes.is_empty() {
        return Err(what("keyframes: expected at least one keyframe".into()));
    }
    let base_fov = match base.projection {
        Projection::Perspective { fov_y_degrees } => fov_y_degrees,
        Projection::Orthographic { .. } => 35.0,
    };
    let mut keys = Vec::with_capacity(json.keyframes.len());
    let mut previous = Keyframe {
        eye: base.eye,
        target: base.target,
        up: base.up,
        fov: base_fov,
    };
    for (i, k) in json.keyframes.iter().enumerate() {
        let key = Keyframe {
            eye: Vec3::from_array(k.eye),
            target: k.target.map(Vec3::from_array).unwrap_or(previous.target),
            up: k.up.map(Vec3::from_array).unwrap_or(previous.up),
            fov: k.fov.unwrap_or(previous.fov),
        };
        let bad = |field: &str, expected: &str| {
            what(format!("keyframes[{i}].{field}: expected {expected}"))
        };
        if !(key.eye.is_finite() && key.target.is_finite()) {
            return Err(bad("eye/target", "finite coordinates"));
        }
        if (key.eye - key.target).length() == 0.0 {
            return Err(bad("eye", "a point away from the target"));
        }
        if !(key.up.is_finite() && key.up.length() > 0.0) {
            return Err(bad("up", "a finite non-zero vector"));
        }
        if !(key.fov > 0.0 && key.fov < 180.0) {
            return Err(bad("fov", "degrees in (0, 180)"));
        }
        keys.push(key);
        previous = key;
    }
    let frames = json.frames.unwrap_or(keys.len() as u32);
    check_frames(&format!("{}: frames", path.display()), frames)?;
    Ok((0..frames)
        .map(|i| {
            let s = if frames == 1 {
                0.0
            } else {
                (keys.len() - 1) as f32 * i as f32 / (frames - 1) as f32
            };
            let segment = (s.floor() as usize).min(keys.len().saturating_sub(2));
            let (a, b) = (keys[segment], keys[(segment + 1).min(keys.len() - 1)]);
            let t = (s - segment as f32).clamp(0.0, 1.0);
            let up = a.up.normalize().lerp(b.up.normalize(), t);
            let up = if up.length() > 1e-6 { up } else { a.up };
            Camera {
                eye: a.eye.lerp(b.eye, t),
                target: a.target.lerp(b.target, t),
                up,
                projection: match base.projection {
                    Projection::Perspective { .. } => Projection::Perspective {
                        fov_y_degrees: a.fov + (b.fov - a.fov) * t,
                    },
                    other => other,
                },
                ..*base
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> Camera {
        Camera::perspective(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 30.0)
    }

    #[test]
    fn an_orbit_keeps_its_distance_and_turns_once() {
        let views = orbit(&base(), 4, None).unwrap();
        assert_eq!(views.len(), 4);
        for v in &views {
            assert!((v.eye.length() - 2.0).abs() < 1e-5);
        }
        // A quarter turn about +y moves +z to +x.
        assert!((views[1].eye - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-5);
        assert!((views[2].eye - Vec3::new(0.0, 0.0, -2.0)).length() < 1e-5);
        let high = orbit(&base(), 2, Some(30.0)).unwrap();
        assert!((high[0].eye.y - 1.0).abs() < 1e-5, "{:?}", high[0].eye);
        assert!(orbit(&base(), 0, None).is_err());
        assert!(orbit(&base(), 3, Some(90.0)).is_err());
    }

    #[test]
    fn a_dolly_ends_at_its_fraction() {
        let views = dolly(&base(), 3, 0.5).unwrap();
        assert_eq!(views[0].eye, Vec3::new(0.0, 0.0, 2.0));
        assert!((views[1].eye.z - 1.5).abs() < 1e-6);
        assert!((views[2].eye.z - 1.0).abs() < 1e-6);
        assert!(dolly(&base(), 3, 0.0).is_err());
    }

    #[test]
    fn keyframes_interpolate_and_errors_name_the_field() {
        let dir = std::env::temp_dir().join(format!("mixvol-path-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("path.json");
        std::fs::write(
            &file,
            r#"{"frames": 5, "keyframes": [
                {"eye": [0, 0, 2], "fov": 20},
                {"eye": [0, 0, 4], "target": [0, 1, 0], "fov": 40}]}"#,
        )
        .unwrap();
        let views = load_path(&file, &base()).unwrap();
        assert_eq!(views.len(), 5);
        assert!((views[2].eye.z - 3.0).abs() < 1e-6);
        assert!((views[2].target.y - 0.5).abs() < 1e-6);
        match views[2].projection {
            Projection::Perspective { fov_y_degrees } => {
                assert!((fov_y_degrees - 30.0).abs() < 1e-4)
            }
            p => panic!("projection {p:?}"),
        }
        assert_eq!(views[4].eye, Vec3::new(0.0, 0.0, 4.0));
        std::fs::write(&file, r#"{"keyframes": [{"eye": [0, 0, 2], "fov": 200}]}"#).unwrap();
        let e = load_path(&file, &base()).unwrap_err().to_string();
        assert!(e.contains("keyframes[0].fov"), "{e}");
        std::fs::write(&file, r#"{"keyframes": [{"eye": [0, 0, 0]}]}"#).unwrap();
        let e = load_path(&file, &base()).unwrap_err().to_string();
        assert!(e.contains("keyframes[0].eye"), "{e}");
        std::fs::write(&file, r#"{"keyframes": [{"eye": [0, 0, 2], "colour": 1}]}"#).unwrap();
        let e = load_path(&file, &base()).unwrap_err().to_string();
        assert!(e.contains("colour"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
