//! The error of the image gradient: forward differences of the image (right and down
//! neighbours, premultiplied RGBA) against the reference's, as an RMS over every difference and
//! channel. A seam is a jump between neighbouring pixels that the reference does not have, so
//! it enters this error at full height, while RMSE divides it by the pixels that it spares.

use super::{Frame, MetricError};
use glam::Vec4;

/// The two forward differences of `frame` at (x, y) that stay inside the frame.
fn differences(frame: &Frame<'_>, x: u32, y: u32) -> [Option<Vec4>; 2] {
    let here = frame.at(x, y);
    [
        (x + 1 < frame.width).then(|| frame.at(x + 1, y) - here),
        (y + 1 < frame.height).then(|| frame.at(x, y + 1) - here),
    ]
}

/// RMS over all horizontal and vertical neighbour pairs and channels of
/// `(I(q) - I(p)) - (R(q) - R(p))`; 0 for frames without a neighbour pair.
pub fn gradient_rmse(image: &Frame<'_>, reference: &Frame<'_>) -> Result<f64, MetricError> {
    image.check_same_size(reference)?;
    let (mut sum, mut count) = (0.0f64, 0usize);
    for y in 0..image.height {
        for x in 0..image.width {
            for (a, b) in differences(image, x, y)
                .into_iter()
                .zip(differences(reference, x, y))
            {
                if let (Some(a), Some(b)) = (a, b) {
                    sum += f64::from((a - b).length_squared());
                    count += 4;
                }
            }
        }
    }
    Ok(if count == 0 {
        0.0
    } else {
        (sum / count as f64).sqrt()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_offset_has_no_gradient_error_and_a_step_has_one() {
        let reference = vec![Vec4::splat(0.2); 16];
        let offset = vec![Vec4::splat(0.6); 16];
        let r = Frame::new(4, 4, &reference).unwrap();
        let e = gradient_rmse(&Frame::new(4, 4, &offset).unwrap(), &r).unwrap();
        assert!(e < 1e-9, "{e}");
        // A vertical step of 0.5 between columns 1 and 2: 4 of the 24 pairs jump.
        let step: Vec<Vec4> = (0..16)
            .map(|i| Vec4::splat(if i % 4 >= 2 { 0.7 } else { 0.2 }))
            .collect();
        let e = gradient_rmse(&Frame::new(4, 4, &step).unwrap(), &r).unwrap();
        assert!((e - (0.25f64 * 4.0 / 24.0).sqrt()).abs() < 1e-6, "{e}");
    }
}
