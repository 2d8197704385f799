//! Drawing primitives of the report charts (bitmaps through the `image` crate): polylines and
//! small bitmap text for tick labels and legends.

/// 3x5 bitmap glyphs for digits, '.', '-' (bit 2 = left column), drawn at twice the size.
pub fn draw_text(img: &mut image::RgbImage, x: i64, y: i64, text: &str, colour: image::Rgb<u8>) {
    const DIGITS: [[u8; 5]; 10] = [
        [7, 5, 5, 5, 7],
        [2, 6, 2, 2, 7],
        [7, 1, 7, 4, 7],
        [7, 1, 7, 1, 7],
        [5, 5, 7, 1, 1],
        [7, 4, 7, 1, 7],
        [7, 4, 7, 5, 7],
        [7, 1, 1, 1, 1],
        [7, 5, 7, 5, 7],
        [7, 5, 7, 1, 7],
    ];
    for (i, ch) in text.chars().enumerate() {
        let glyph = match ch {
            '0'..='9' => DIGITS[ch as usize - '0' as usize],
            '.' => [0, 0, 0, 0, 2],
            '-' => [0, 0, 7, 0, 0],
            _ => continue,
        };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    for s in 0..4 {
                        let px = x + i as i64 * 8 + col * 2 + (s & 1);
                        let py = y + row as i64 * 2 + (s >> 1);
                        if px >= 0
                            && py >= 0
                            && (px as u32) < img.width()
                            && (py as u32) < img.height()
                        {
                            img.put_pixel(px as u32, py as u32, colour);
                        }
                    }
                }
            }
        }
    }
}

/// A two-pixel-wide polyline; dashed: 8 pixels on, 6 off along its length.
pub fn draw_polyline(
    img: &mut image::RgbImage,
    points: &[(f64, f64)],
    colour: image::Rgb<u8>,
    dashed: bool,
) {
    let mut travelled = 0.0f64;
    for pair in points.windows(2) {
        let ((x0, y0), (x1, y1)) = (pair[0], pair[1]);
        let len = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
        let steps = (len * 2.0).ceil().max(1.0) as usize;
        for s in 0..=steps {
            let f = s as f64 / steps as f64;
            if dashed && (travelled + f * len) % 14.0 >= 8.0 {
                continue;
            }
            let (x, y) = (x0 + f * (x1 - x0), y0 + f * (y1 - y0));
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (px, py) = (x as i64 + dx, y as i64 + dy);
                if px >= 0 && py >= 0 && (px as u32) < img.width() && (py as u32) < img.height() {
                    img.put_pixel(px as u32, py as u32, colour);
                }
            }
        }
        travelled += len;
    }
}

/// Text in the style of the report's tick labels: digits, '.' and '-' through
/// [`draw_text`], plus 3x5 capitals and ':', '=' (other characters leave a gap).
pub fn draw_label(img: &mut image::RgbImage, x: i64, y: i64, text: &str, colour: image::Rgb<u8>) {
    const LETTERS: [[u8; 5]; 26] = [
        [2, 5, 7, 5, 5],
        [6, 5, 6, 5, 6],
        [3, 4, 4, 4, 3],
        [6, 5, 5, 5, 6],
        [7, 4, 6, 4, 7],
        [7, 4, 6, 4, 4],
        [3, 4, 5, 5, 3],
        [5, 5, 7, 5, 5],
        [7, 2, 2, 2, 7],
        [1, 1, 1, 5, 2],
        [5, 5, 6, 5, 5],
        [4, 4, 4, 4, 7],
        [5, 7, 7, 5, 5],
        [6, 5, 5, 5, 5],
        [2, 5, 5, 5, 2],
        [6, 5, 6, 4, 4],
        [2, 5, 5, 6, 3],
        [6, 5, 6, 5, 5],
        [3, 4, 2, 1, 6],
        [7, 2, 2, 2, 2],
        [5, 5, 5, 5, 7],
        [5, 5, 5, 5, 2],
        [5, 5, 7, 7, 5],
        [5, 5, 2, 5, 5],
        [5, 5, 2, 2, 2],
        [7, 1, 2, 4, 7],
    ];
    for (i, ch) in text.chars().enumerate() {
        let cx = x + i as i64 * 8;
        let glyph = match ch.to_ascii_uppercase() {
            c @ ('0'..='9' | '.' | '-') => {
                let mut buf = [0u8; 4];
                draw_text(img, cx, y, c.encode_utf8(&mut buf), colour);
                continue;
            }
            c @ 'A'..='Z' => LETTERS[c as usize - 'A' as usize],
            ':' => [0, 2, 0, 2, 0],
            '=' => [0, 7, 0, 7, 0],
            _ => continue,
        };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..3i64 {
                if bits & (4 >> col) != 0 {
                    for s in 0..4i64 {
                        let (px, py) = (cx + col * 2 + (s & 1), y + row as i64 * 2 + (s >> 1));
                        if px >= 0
                            && py >= 0
                            && (px as u32) < img.width()
                            && (py as u32) < img.height()
                        {
                            img.put_pixel(px as u32, py as u32, colour);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::draw_label;

    #[test]
    fn glyphs_are_drawn_and_clipped() {
        let mut img = image::RgbImage::new(40, 12);
        draw_label(&mut img, 0, 0, "A1=", image::Rgb([255, 255, 255]));
        assert!(img.pixels().any(|p| p.0[0] == 255));
        // Off-image text is clipped, not a panic.
        draw_label(&mut img, -100, 1000, "ZZZ", image::Rgb([255, 0, 0]));
    }
}
