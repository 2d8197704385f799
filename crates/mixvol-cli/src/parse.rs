//! Parsers of flag values (`x,y,z` vectors, scalar types, transfer-function presets), each
//! saying what it expected.

use glam::{UVec3, Vec3};
use mixvol::optics::TfPreset;
use mixvol::volume::ScalarType;

pub fn parse_floats<const N: usize>(s: &str) -> std::result::Result<[f32; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!("expected {N} comma-separated numbers, got '{s}'"));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.parse().map_err(|_| format!("'{p}' is not a number"))?;
    }
    Ok(out)
}

pub fn parse_vec3(s: &str) -> std::result::Result<Vec3, String> {
    parse_floats::<3>(s).map(Vec3::from_array)
}

/// A colour `r,g,b`, each a number in [0, 1] (NaN and values past 1 were taken silently and
/// gave black or white: review D29).
pub fn parse_colour(s: &str) -> std::result::Result<Vec3, String> {
    let rgb = parse_floats::<3>(s)?;
    if rgb.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(format!("expected r,g,b each in [0, 1], got '{s}'"));
    }
    Ok(Vec3::from_array(rgb))
}

pub fn parse_uvec3(s: &str) -> std::result::Result<UVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected x,y,z (three integers), got '{s}'"));
    }
    let mut out = [0u32; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p
            .parse()
            .map_err(|_| format!("'{p}' is not a non-negative integer"))?;
    }
    Ok(UVec3::from_array(out))
}

pub fn parse_scalar(s: &str) -> std::result::Result<ScalarType, String> {
    ScalarType::parse(s).ok_or_else(|| format!("unknown scalar type '{s}' (u8, u16, f32)"))
}

pub fn parse_tf(s: &str) -> std::result::Result<TfPreset, String> {
    TfPreset::parse(s).ok_or_else(|| format!("unknown preset '{s}' ({})", TfPreset::NAMES))
}
