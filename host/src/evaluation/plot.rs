//! Plots as SVG and PNG (plotters; the PNG text is drawn with DejaVu Sans,
//! bundled in `host/assets/`, and encoded with the `png` crate).
//!
//! Every line plot draws error bars of one standard error where the series
//! has them, and marks values beyond the y range with an arrow at the edge
//! and the value, so that a clipped point never looks like a plateau.
//! Image panels ([`write_images`]) show spots pixel by pixel.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{anyhow, Context, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Colours for cases (colour-blind-friendly: Okabe-Ito, then greys).
pub const COLORS: [RGBColor; 10] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
    RGBColor(120, 120, 120),
    RGBColor(160, 60, 60),
    RGBColor(60, 60, 160),
];

/// Point marker of a series.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    None,
    Circle,
    Triangle,
    Square,
    Cross,
}

/// One curve.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub color: RGBColor,
    pub marker: Marker,
    pub dashed: bool,
    pub points: Vec<(f64, f64)>,
    /// One standard error per point (empty: none drawn).
    pub errors: Vec<f64>,
    /// Draw a large ring around the last point (the "all pixels" point).
    pub ring_last: bool,
}

impl Series {
    /// A solid line with markers and no error bars.
    pub fn line(label: impl Into<String>, color: RGBColor, marker: Marker) -> Series {
        Series {
            label: label.into(),
            color,
            marker,
            dashed: false,
            points: Vec::new(),
            errors: Vec::new(),
            ring_last: false,
        }
    }
}

/// A whole plot.
#[derive(Clone, Debug)]
pub struct Plot {
    pub title: String,
    pub x_desc: String,
    pub y_desc: String,
    pub x_log: bool,
    pub series: Vec<Series>,
    /// Y range; `None`: from the data (see [`auto_y_range`]).
    pub y_range: Option<Range<f64>>,
}

/// `0 .. 1.05 max`, but if some curve rises far above the others' minima
/// (e.g. N = 1), the top is capped at 3x the largest curve minimum so the
/// interesting region stays readable; points above are marked off-scale.
pub fn auto_y_range(series: &[Series]) -> Range<f64> {
    let all = series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
    let max = all.clone().fold(f64::NEG_INFINITY, f64::max);
    let min = all.fold(f64::INFINITY, f64::min);
    let largest_minimum = series
        .iter()
        .map(|s| s.points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min))
        .filter(|v| v.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    let top = if max > 3.0 * largest_minimum && largest_minimum > 0.0 {
        3.0 * largest_minimum
    } else {
        max * 1.05
    };
    let bottom = if min < 0.0 { min * 1.05 } else { 0.0 };
    if top.is_finite() && top > bottom {
        bottom..top
    } else {
        0.0..1.0
    }
}

fn x_range(plot: &Plot) -> Range<f64> {
    let xs = plot
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.0));
    let lo = xs.clone().fold(f64::INFINITY, f64::min);
    let hi = xs.fold(f64::NEG_INFINITY, f64::max);
    if !(lo.is_finite() && hi.is_finite()) {
        return 0.0..1.0;
    }
    if plot.x_log {
        (lo.max(1e-3) / 1.15)..(hi * 1.15)
    } else {
        let pad = 0.02 * (hi - lo).max(1e-9);
        (lo - pad)..(hi + pad)
    }
}

/// Width of the legend column on the right of every plot (pixels).
const LEGEND_WIDTH: u32 = 270;

static FONT: Once = Once::new();

/// Registers the bundled font for the bitmap backend (once).
fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../assets/DejaVuSans.ttf");
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .unwrap_or_else(|_| panic!("the bundled DejaVuSans.ttf is a valid font"));
    });
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("{e:?}")
}

/// Writes `plot` as `{stem}.svg` and `{stem}.png` of `size` pixels (the
/// legend is a column on the right, outside the axes, so it never hides
/// data); returns both paths.
pub fn write(stem: &Path, plot: &Plot, size: (u32, u32)) -> Result<Vec<PathBuf>> {
    register_font();
    let svg = stem.with_extension("svg");
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        draw_plot(&root, plot)?;
        root.present()
            .map_err(err)
            .with_context(|| svg.display().to_string())?;
    }
    let png = stem.with_extension("png");
    let mut buffer = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        draw_plot(&root, plot)?;
        root.present().map_err(err)?;
    }
    write_png(&png, &buffer, size)?;
    Ok(vec![svg, png])
}

/// Encodes an RGB buffer as PNG.
fn write_png(path: &Path, rgb: &[u8], (w, h): (u32, u32)) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::High);
    let mut writer = encoder
        .write_header()
        .with_context(|| path.display().to_string())?;
    writer
        .write_image_data(rgb)
        .with_context(|| path.display().to_string())?;
    writer
        .finish()
        .with_context(|| path.display().to_string())?;
    Ok(())
}

fn draw_plot<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, plot: &Plot) -> Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let (w, _) = root.dim_in_pixel();
    let (chart_area, legend_area) = root.split_horizontally(w.saturating_sub(LEGEND_WIDTH));
    let y = plot
        .y_range
        .clone()
        .unwrap_or_else(|| auto_y_range(&plot.series));
    let x = x_range(plot);
    if plot.x_log {
        draw(&chart_area, plot, x.log_scale(), y)?;
    } else {
        draw(&chart_area, plot, x, y)?;
    }
    draw_legend(&legend_area, plot)
}

/// Tick label: integers without decimals, others with up to 3.
fn tick(v: f64) -> String {
    if v == v.round() && v.abs() < 1e9 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

fn draw_legend<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, plot: &Plot) -> Result<()> {
    let font = ("sans-serif", 12).into_font().color(&BLACK);
    let mut y = 50;
    for s in &plot.series {
        let style = s.color.stroke_width(2);
        if s.dashed {
            for x0 in [4, 14] {
                area.draw(&PathElement::new(vec![(x0, y), (x0 + 7, y)], style))
                    .map_err(err)?;
            }
        } else {
            area.draw(&PathElement::new(vec![(4, y), (26, y)], style))
                .map_err(err)?;
        }
        draw_marker(area, s.marker, (15, y), s.color)?;
        area.draw(&Text::new(s.label.clone(), (32, y - 6), font.clone()))
            .map_err(err)?;
        y += 18;
    }
    let has_errors = plot.series.iter().any(|s| !s.errors.is_empty());
    let small = ("sans-serif", 11).into_font().color(&RGBColor(90, 90, 90));
    y += 10;
    if has_errors {
        for line in [
            "bars: +-1 standard error",
            "(hidden by the marker",
            " where smaller than it)",
        ] {
            area.draw(&Text::new(line, (4, y), small.clone()))
                .map_err(err)?;
            y += 14;
        }
    }
    for line in ["arrow at the edge + value:", "point beyond the axis range"] {
        area.draw(&Text::new(line, (4, y), small.clone()))
            .map_err(err)?;
        y += 14;
    }
    Ok(())
}

fn draw_marker<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    marker: Marker,
    (x, y): (i32, i32),
    color: RGBColor,
) -> Result<()> {
    let filled = color.filled();
    match marker {
        Marker::None => {}
        Marker::Circle => area.draw(&Circle::new((x, y), 3, filled)).map_err(err)?,
        Marker::Triangle => area
            .draw(&TriangleMarker::new((x, y), 4, filled))
            .map_err(err)?,
        Marker::Square => area
            .draw(&Rectangle::new([(x - 3, y - 3), (x + 3, y + 3)], filled))
            .map_err(err)?,
        Marker::Cross => area
            .draw(&Cross::new((x, y), 4, color.stroke_width(2)))
            .map_err(err)?,
    }
    Ok(())
}

fn draw<DB: DrawingBackend, X>(
    root: &DrawingArea<DB, Shift>,
    plot: &Plot,
    x: X,
    y: Range<f64>,
) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
{
    let (y_lo, y_hi) = (y.start, y.end);
    let mut chart = ChartBuilder::on(root)
        .caption(&plot.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(plot.x_desc.as_str())
        .y_desc(plot.y_desc.as_str())
        .light_line_style(RGBColor(240, 240, 240))
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    let clamp = |(px, py): (f64, f64)| (px, py.clamp(y_lo, y_hi));
    let font = ("sans-serif", 11).into_font();
    for s in &plot.series {
        let color = s.color;
        let pts: Vec<(f64, f64)> = s.points.iter().copied().map(clamp).collect();
        let style = color.stroke_width(2);
        if s.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts.clone(), 7, 5, style))
                .map_err(err)?;
        } else {
            chart
                .draw_series(LineSeries::new(pts.clone(), style))
                .map_err(err)?;
        }
        // Error bars (clamped to the axes).
        for (&(px, py), &e) in s.points.iter().zip(&s.errors) {
            if e.is_nan() || e <= 0.0 || py > y_hi || py < y_lo {
                continue;
            }
            let (a, b) = ((py - e).max(y_lo), (py + e).min(y_hi));
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(px, a), (px, b)],
                    color.stroke_width(1),
                )))
                .map_err(err)?;
            for end in [a, b] {
                chart
                    .draw_series(std::iter::once(
                        EmptyElement::at((px, end))
                            + PathElement::new(vec![(-3, 0), (3, 0)], color.stroke_width(1)),
                    ))
                    .map_err(err)?;
            }
        }
        for (&raw, &p) in s.points.iter().zip(&pts) {
            if raw.1 > y_hi || raw.1 < y_lo {
                // Off-scale: an arrow at the edge and the value.
                let up = raw.1 > y_hi;
                let (tip, tail) = if up { (-10, 4) } else { (10, -4) };
                chart
                    .draw_series(std::iter::once(
                        EmptyElement::at(p)
                            + Polygon::new(vec![(-5, tail), (5, tail), (0, tip)], color.filled())
                            + Text::new(
                                tick((raw.1 * 100.0).round() / 100.0),
                                (6, if up { 2 } else { -14 }),
                                font.clone().color(&color),
                            ),
                    ))
                    .map_err(err)?;
                continue;
            }
            let filled = color.filled();
            match s.marker {
                Marker::None => {}
                Marker::Circle => {
                    chart
                        .draw_series(std::iter::once(Circle::new(p, 3, filled)))
                        .map_err(err)?;
                }
                Marker::Triangle => {
                    chart
                        .draw_series(std::iter::once(TriangleMarker::new(p, 4, filled)))
                        .map_err(err)?;
                }
                Marker::Square => {
                    chart
                        .draw_series(std::iter::once(
                            EmptyElement::at(p) + Rectangle::new([(-3, -3), (3, 3)], filled),
                        ))
                        .map_err(err)?;
                }
                Marker::Cross => {
                    chart
                        .draw_series(std::iter::once(Cross::new(p, 4, color.stroke_width(2))))
                        .map_err(err)?;
                }
            }
        }
        if s.ring_last {
            if let Some(&last) = pts.last() {
                chart
                    .draw_series(std::iter::once(Circle::new(last, 7, color.stroke_width(2))))
                    .map_err(err)?;
            }
        }
    }
    Ok(())
}

/// One image of [`write_images`]: a `size x size` image, row-major.
#[derive(Clone, Debug)]
pub struct ImagePanel {
    pub title: String,
    pub size: usize,
    pub values: Vec<f64>,
}

/// Writes `{stem}.svg` and `{stem}.png`: the panels in `columns` columns,
/// each image normalised to its own maximum (linear grey scale, white =
/// brightest), with the title above; `caption` on top.
pub fn write_images(
    stem: &Path,
    caption: &str,
    panels: &[ImagePanel],
    columns: usize,
    cell: u32,
) -> Result<Vec<PathBuf>> {
    register_font();
    let rows = panels.len().div_ceil(columns.max(1)) as u32;
    let size = (columns as u32 * (cell + 20) + 20, rows * (cell + 40) + 50);
    let svg = stem.with_extension("svg");
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        draw_images(&root, caption, panels, columns, cell)?;
        root.present().map_err(err)?;
    }
    let png = stem.with_extension("png");
    let mut buffer = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        draw_images(&root, caption, panels, columns, cell)?;
        root.present().map_err(err)?;
    }
    write_png(&png, &buffer, size)?;
    Ok(vec![svg, png])
}

fn draw_images<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    caption: &str,
    panels: &[ImagePanel],
    columns: usize,
    cell: u32,
) -> Result<()> {
    root.fill(&WHITE).map_err(err)?;
    root.draw(&Text::new(
        caption.to_string(),
        (20, 12),
        ("sans-serif", 15).into_font(),
    ))
    .map_err(err)?;
    for (k, p) in panels.iter().enumerate() {
        let (col, row) = ((k % columns) as i32, (k / columns) as i32);
        let x0 = 20 + col * (cell as i32 + 20);
        let y0 = 50 + row * (cell as i32 + 40);
        root.draw(&Text::new(
            p.title.clone(),
            (x0, y0 - 4),
            ("sans-serif", 12).into_font(),
        ))
        .map_err(err)?;
        let max = p.values.iter().copied().fold(f64::MIN_POSITIVE, f64::max);
        let px = cell as f64 / p.size as f64;
        for (i, &v) in p.values.iter().enumerate() {
            let (x, y) = ((i % p.size) as f64, (i / p.size) as f64);
            let g = (255.0 * (v / max).clamp(0.0, 1.0)).round() as u8;
            let a = (x0 + (x * px) as i32, y0 + 10 + (y * px) as i32);
            let b = (
                x0 + ((x + 1.0) * px) as i32,
                y0 + 10 + ((y + 1.0) * px) as i32,
            );
            root.draw(&Rectangle::new([a, b], RGBColor(g, g, g).filled()))
                .map_err(err)?;
        }
        root.draw(&Rectangle::new(
            [(x0, y0 + 10), (x0 + cell as i32, y0 + 10 + cell as i32)],
            RGBColor(200, 0, 0).stroke_width(1),
        ))
        .map_err(err)?;
    }
    Ok(())
}
