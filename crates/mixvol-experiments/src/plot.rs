//! The report charts, drawn with `plotters` (bitmap and SVG backends, text through its pure-Rust
//! `ab_glyph` path with DejaVu Sans from the `dejavu` crate: no fontconfig, no freetype).
//!
//! A [`Chart`] is one or more side-by-side [`Panel`]s of line series over linear axes; each
//! [`Series`] joins its points with a line (solid or dashed), marks them, labels each point with
//! its setting, and appears in the panel's legend.

use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;
use thiserror::Error;

/// Why a chart could not be drawn or written.
#[derive(Debug, Error)]
pub enum PlotError {
    /// The embedded font could not be registered with plotters.
    #[error("the embedded DejaVu Sans font was refused")]
    Font,
    /// Plotters failed while drawing.
    #[error("drawing the chart: {0}")]
    Draw(String),
    /// Writing a chart file failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// One line of a panel.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// Line colour (RGB).
    pub colour: [u8; 3],
    /// Dashed instead of solid.
    pub dashed: bool,
    /// The points in drawing order (x, y).
    pub points: Vec<(f64, f64)>,
    /// A label per point (the setting), drawn beside it; empty strings draw nothing.
    pub labels: Vec<String>,
}

/// One plot: axes with titles (units included by the caller), its series and a legend.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Caption above the plot.
    pub title: String,
    /// X axis title.
    pub x_label: String,
    /// Y axis title.
    pub y_label: String,
    /// Fixed y range; `None` fits the data.
    pub y_range: Option<(f64, f64)>,
    /// The series.
    pub series: Vec<Series>,
    /// Legend in the upper left corner instead of the upper right.
    pub legend_left: bool,
    /// Logarithmic y axis (for errors spanning decades); points with y <= 0 are left out (a
    /// zero error has no place on it).
    pub log_y: bool,
}

/// Panels side by side under a title.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    /// Title over all panels.
    pub title: String,
    /// The panels, left to right.
    pub panels: Vec<Panel>,
    /// Pixel size of one panel (the SVG uses the same units).
    pub panel_size: (u32, u32),
}

/// Colours of the report's series, in order.
pub const PALETTE: [[u8; 3]; 11] = [
    [30, 90, 220],
    [20, 150, 60],
    [230, 120, 10],
    [200, 30, 30],
    [130, 60, 180],
    [90, 90, 90],
    [0, 170, 190],
    [190, 150, 0],
    [220, 60, 150],
    [110, 70, 30],
    [0, 0, 0],
];

const FONT: &str = "sans-serif";

fn register_font() -> Result<(), PlotError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

fn draw_err(e: impl std::fmt::Display) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// The range `[lo, hi]` of `values` widened by 8% each side (and to a non-empty interval).
fn padded(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(hi.abs().max(1e-9) * 0.05);
    (lo - pad, hi + pad)
}

impl Chart {
    /// Width and height of the whole chart in pixels.
    pub fn size(&self) -> (u32, u32) {
        (
            self.panel_size.0 * self.panels.len().max(1) as u32,
            self.panel_size.1 + 40,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), PlotError>
    where
        DB::ErrorType: 'static,
    {
        register_font()?;
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root.titled(&self.title, (FONT, 20)).map_err(draw_err)?;
        let areas = root.split_evenly((1, self.panels.len().max(1)));
        for (panel, area) in self.panels.iter().zip(areas) {
            // On a log axis the chart runs over log10(y) with labels at 10^v.
            let to_axis = |y: f64| {
                if !panel.log_y {
                    y
                } else if y > 0.0 {
                    y.log10()
                } else {
                    f64::NAN
                }
            };
            let points = || {
                panel
                    .series
                    .iter()
                    .flat_map(|s| s.points.iter().map(|p| (p.0, to_axis(p.1))))
            };
            let (x0, x1) = padded(points().map(|p| p.0));
            let (y0, y1) = panel
                .y_range
                .map(|(a, b)| (to_axis(a), to_axis(b)))
                .unwrap_or_else(|| padded(points().map(|p| p.1)));
            let log_y = panel.log_y;
            let y_format = move |v: &f64| {
                if log_y {
                    format!("{:.1e}", 10f64.powf(*v))
                } else {
                    format!("{v:.3}")
                }
            };
            let mut chart = ChartBuilder::on(&area)
                .caption(&panel.title, (FONT, 16))
                .margin(12)
                .x_label_area_size(44)
                .y_label_area_size(64)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc(&panel.x_label)
                .y_desc(&panel.y_label)
                .y_label_formatter(&y_format)
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 14))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(draw_err)?;
            // Label anchors already drawn (pixels): a label that would overlap one is left out.
            let mut placed: Vec<(i32, i32)> = Vec::new();
            for s in &panel.series {
                let colour = RGBColor(s.colour[0], s.colour[1], s.colour[2]);
                let style = colour.stroke_width(2);
                let inside: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .map(|(x, y)| (x, to_axis(y)))
                    .filter(|p| p.0.is_finite() && p.1.is_finite())
                    .map(|(x, y)| (x, y.clamp(y0, y1)))
                    .collect();
                let labels: Vec<(&(f64, f64), &String)> = inside
                    .iter()
                    .zip(
                        s.points
                            .iter()
                            .zip(&s.labels)
                            .filter(|(p, _)| p.0.is_finite() && to_axis(p.1).is_finite())
                            .map(|(_, l)| l),
                    )
                    .filter(|(p, l)| {
                        if l.is_empty() {
                            return false;
                        }
                        let (px, py) = chart.backend_coord(p);
                        let w = 7 * l.chars().count() as i32 + 6;
                        let free = placed
                            .iter()
                            .all(|&(qx, qy)| (px - qx).abs() > w || (py - qy).abs() > 12);
                        if free {
                            placed.push((px, py));
                        }
                        free
                    })
                    .collect();
                let legend = move |(x, y): (i32, i32)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(2))
                };
                if s.dashed {
                    chart
                        .draw_series(DashedLineSeries::new(inside.clone(), 7, 5, style))
                        .map_err(draw_err)?
                        .label(&s.name)
                        .legend(move |(x, y)| {
                            EmptyElement::at((x, y))
                                + PathElement::new(vec![(0, 0), (8, 0)], colour.stroke_width(2))
                                + PathElement::new(vec![(14, 0), (24, 0)], colour.stroke_width(2))
                        });
                } else {
                    chart
                        .draw_series(LineSeries::new(inside.clone(), style))
                        .map_err(draw_err)?
                        .label(&s.name)
                        .legend(legend);
                }
                chart
                    .draw_series(inside.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(draw_err)?;
                let font = (FONT, 11).into_font().color(&colour);
                chart
                    .draw_series(labels.into_iter().map(|(&p, l)| {
                        EmptyElement::at(p) + Text::new(l.clone(), (5, -14), font.clone())
                    }))
                    .map_err(draw_err)?;
            }
            chart
                .configure_series_labels()
                .position(if panel.legend_left {
                    SeriesLabelPosition::UpperLeft
                } else {
                    SeriesLabelPosition::UpperRight
                })
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font((FONT, 12))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)
    }

    /// The chart as an RGB bitmap.
    pub fn to_png_image(&self) -> Result<image::RgbImage, PlotError> {
        let (w, h) = self.size();
        let mut buffer = vec![0u8; w as usize * h as usize * 3];
        self.draw(BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area())?;
        image::RgbImage::from_raw(w, h, buffer)
            .ok_or_else(|| PlotError::Draw("bitmap buffer of the wrong size".into()))
    }

    /// The chart as an SVG document.
    pub fn to_svg(&self) -> Result<String, PlotError> {
        let mut svg = String::new();
        self.draw(SVGBackend::with_string(&mut svg, self.size()).into_drawing_area())?;
        Ok(svg)
    }

    /// Writes `<stem>.png` and `<stem>.svg` into `dir`.
    pub fn write(&self, dir: &Path, stem: &str) -> Result<(), PlotError> {
        let write_err = |path: std::path::PathBuf, e: &dyn std::fmt::Display| PlotError::Write {
            path,
            message: e.to_string(),
        };
        let png = dir.join(format!("{stem}.png"));
        self.to_png_image()?
            .save(&png)
            .map_err(|e| write_err(png.clone(), &e))?;
        let svg = dir.join(format!("{stem}.svg"));
        mixvol::output::write_file_atomically(&svg, self.to_svg()?.as_bytes())
            .map_err(|e| write_err(svg.clone(), &e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chart() -> Chart {
        Chart {
            title: "t".into(),
            panels: vec![Panel {
                title: "p".into(),
                x_label: "frame time (ms)".into(),
                y_label: "RMSE".into(),
                y_range: None,
                series: vec![Series {
                    name: "steps".into(),
                    colour: PALETTE[0],
                    dashed: true,
                    points: vec![(1.0, 0.3), (2.0, 0.1), (f64::NAN, 1.0)],
                    labels: vec!["0.5".into(), "1".into(), String::new()],
                }],
                legend_left: false,
                log_y: false,
            }],
            panel_size: (320, 240),
        }
    }

    #[test]
    fn charts_draw_text_lines_and_both_formats() {
        let c = chart();
        let img = c.to_png_image().unwrap();
        assert_eq!(img.dimensions(), (320, 280));
        // The series colour and dark text pixels are present.
        assert!(img.pixels().any(|p| p.0 == PALETTE[0]));
        assert!(
            img.pixels()
                .filter(|p| p.0[0] < 80 && p.0[1] < 80 && p.0[2] < 80)
                .count()
                > 200
        );
        let svg = c.to_svg().unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("frame time (ms)") && svg.contains("\nsteps\n")
        );
    }

    #[test]
    fn log_axis_leaves_out_zeros_and_labels_decades() {
        let mut c = chart();
        let panel = &mut c.panels[0];
        panel.log_y = true;
        panel.series[0].points = vec![(1.0, 0.0), (2.0, 0.01), (3.0, 0.001)];
        panel.series[0].labels = vec!["zero".into(), "a".into(), "b".into()];
        // Two labels at the same place: only the first is drawn.
        panel.series.push(Series {
            name: "twin".into(),
            colour: PALETTE[1],
            dashed: false,
            points: vec![(2.0, 0.01)],
            labels: vec!["twin".into()],
        });
        let svg = c.to_svg().unwrap();
        // Ticks are powers of ten written as such; the zero point has no place (its label is
        // not drawn), nor has the overlapping twin label.
        assert!(svg.contains("e-2") || svg.contains("e-3"), "{svg}");
        assert_eq!(svg.matches("\nzero\n").count(), 0);
        assert_eq!(svg.matches("\na\n").count(), 1);
        assert_eq!(svg.matches("\nb\n").count(), 1);
        // "twin" once: its legend entry.
        assert_eq!(svg.matches("\ntwin\n").count(), 1);
        c.to_png_image().unwrap();
    }
}
