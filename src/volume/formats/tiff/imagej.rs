//! ImageJ / Fiji hyperstacks: the `key=value` lines ImageJ writes in the first page's
//! `ImageDescription` (`ImageJ=1.54f`, `images=`, `channels=`, `slices=`, `frames=`,
//! `spacing=`, `unit=`). Pages are in CZT order (channel fastest); x / y voxel sizes are the
//! `XResolution` / `YResolution` tags (pixels per `unit`), z the `spacing`.

use super::ome::micrometres_per;

/// What an ImageJ description says.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageJ {
    /// `channels` (default 1).
    pub channels: u64,
    /// `slices` (default: `images / (channels * frames)`).
    pub slices: u64,
    /// `frames` (default 1).
    pub frames: u64,
    /// `spacing`: the z voxel size in `unit`, when given.
    pub spacing: Option<f64>,
    /// `unit` (`micron`, `nm`, `mm`, ...), when given.
    pub unit: Option<String>,
}

impl ImageJ {
    /// Parses a description starting with `ImageJ=`; `None` for any other text. Values that do
    /// not parse count as absent; sizes of 0 as 1.
    pub fn parse(description: &str) -> Option<Self> {
        if !description.trim_start().starts_with("ImageJ=") {
            return None;
        }
        let mut get = std::collections::HashMap::new();
        for line in description.lines() {
            if let Some((k, v)) = line.split_once('=') {
                get.entry(k.trim()).or_insert(v.trim());
            }
        }
        let count = |k: &str| {
            get.get(k)
                .and_then(|v| v.parse::<u64>().ok())
                .map(|n| n.max(1))
        };
        let channels = count("channels").unwrap_or(1);
        let frames = count("frames").unwrap_or(1);
        let slices = count("slices").unwrap_or_else(|| {
            let images = count("images").unwrap_or(1);
            (images / channels.saturating_mul(frames)).max(1)
        });
        let spacing = get
            .get("spacing")
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|s| s.is_finite() && *s > 0.0);
        Some(Self {
            channels,
            slices,
            frames,
            spacing,
            unit: get.get("unit").map(|u| u.to_string()),
        })
    }

    /// The page of (z, c, t), CZT order; `None` on overflow.
    pub fn page_of(&self, z: u64, c: u64, t: u64) -> Option<u64> {
        t.checked_mul(self.slices)?
            .checked_add(z)?
            .checked_mul(self.channels)?
            .checked_add(c)
    }

    /// Micrometres per `unit`; `None` when the unit is absent or not a known length (the sizes
    /// then stay in the file's unit, so their ratios still hold).
    pub fn micrometres_per_unit(&self) -> Option<f64> {
        let unit = self.unit.as_deref()?;
        // ImageJ escapes the micro sign as `\u00B5m` in its descriptions.
        let unit = unit.replace("\\u00B5", "\u{b5}");
        micrometres_per(&unit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hyperstack_keys_parse() {
        let d = "ImageJ=1.11a\nimages=24\nchannels=2\nslices=4\nframes=3\nhyperstack=true\n\
                 spacing=2.5\nunit=\\u00B5m\n";
        let ij = ImageJ::parse(d).unwrap();
        assert_eq!((ij.channels, ij.slices, ij.frames), (2, 4, 3));
        assert_eq!(ij.spacing, Some(2.5));
        assert_eq!(ij.micrometres_per_unit(), Some(1.0));
        assert_eq!(ij.page_of(1, 1, 2), Some(1 + 2 * (1 + 4 * 2)));
        let plain = ImageJ::parse("ImageJ=1.11a\nimages=7\n").unwrap();
        assert_eq!((plain.channels, plain.slices, plain.frames), (1, 7, 1));
        assert!(ImageJ::parse("{\"shape\": [3, 4, 5]}").is_none());
    }
}
