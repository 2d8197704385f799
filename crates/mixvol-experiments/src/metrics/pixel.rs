//! Per-pixel error: RMSE of premultiplied RGBA and the PSNR it implies. Blind to where the error
//! sits: a seam of a few pixels barely moves it.

use super::{Frame, MetricError};

/// Root-mean-square error over all pixels and the four channels, in [0, 1].
pub fn rmse(image: &Frame<'_>, reference: &Frame<'_>) -> Result<f64, MetricError> {
    image.check_same_size(reference)?;
    let sum: f64 = image
        .pixels
        .iter()
        .zip(reference.pixels)
        .map(|(a, b)| f64::from((*a - *b).length_squared()))
        .sum();
    Ok((sum / (4 * image.pixels.len().max(1)) as f64).sqrt())
}

/// Peak signal-to-noise ratio in dB for a peak of 1 (infinite for an exact match).
pub fn psnr(rmse: f64) -> f64 {
    if rmse > 0.0 {
        20.0 * (1.0 / rmse).log10()
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

    #[test]
    fn rmse_of_a_constant_offset_is_the_offset() {
        let a = vec![Vec4::splat(0.5); 6];
        let b = vec![Vec4::splat(0.25); 6];
        let e = rmse(
            &Frame::new(3, 2, &a).unwrap(),
            &Frame::new(3, 2, &b).unwrap(),
        )
        .unwrap();
        assert!((e - 0.25).abs() < 1e-9);
        assert!((psnr(0.1) - 20.0).abs() < 1e-9);
        assert!(psnr(0.0).is_infinite());
        assert!(Frame::new(2, 2, &a).is_err());
        let c = vec![Vec4::ZERO; 6];
        assert!(rmse(
            &Frame::new(3, 2, &a).unwrap(),
            &Frame::new(2, 3, &c).unwrap()
        )
        .is_err());
    }
}
