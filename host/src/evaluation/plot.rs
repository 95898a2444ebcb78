//! Line plots as SVG (plotters, no fonts needed: text stays SVG `<text>`).

use std::ops::Range;
use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
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
    /// Draw a large ring around the last point (the "all pixels" point).
    pub ring_last: bool,
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
/// interesting region stays readable; points above are drawn at the top.
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
    if plot.x_log {
        (lo.max(1e-3) / 1.15)..(hi * 1.15)
    } else {
        let pad = 0.02 * (hi - lo).max(1e-9);
        (lo - pad)..(hi + pad)
    }
}

/// Width of the legend column on the right of every plot (pixels).
const LEGEND_WIDTH: u32 = 250;

/// Writes `plot` as an SVG of `size` pixels (the legend is a column on the
/// right, outside the axes, so it never hides data).
pub fn write_svg(path: &Path, plot: &Plot, size: (u32, u32)) -> Result<()> {
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e:?}"))?;
    let (chart_area, legend_area) = root.split_horizontally(size.0.saturating_sub(LEGEND_WIDTH));
    let y = plot
        .y_range
        .clone()
        .unwrap_or_else(|| auto_y_range(&plot.series));
    let x = x_range(plot);
    let clipped = plot
        .series
        .iter()
        .flat_map(|s| s.points.iter())
        .any(|p| p.1 > y.end || p.1 < y.start);
    let mut plot = plot.clone();
    if clipped {
        plot.y_desc
            .push_str(" [off-scale values drawn at the edge]");
    }
    let plot = &plot;
    if plot.x_log {
        draw(&chart_area, plot, x.log_scale(), y)?;
    } else {
        draw(&chart_area, plot, x, y)?;
    }
    draw_legend(&legend_area, plot)?;
    root.present()
        .map_err(|e| anyhow!("{}: {e:?}", path.display()))?;
    Ok(())
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

fn draw_legend(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    plot: &Plot,
) -> Result<()> {
    let err = |e: DrawingAreaErrorKind<_>| anyhow!("{e:?}");
    let font = ("sans-serif", 12).into_font().color(&BLACK);
    for (i, s) in plot.series.iter().enumerate() {
        let y = 50 + 18 * i as i32;
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
        let filled = s.color.filled();
        let at = (15, y);
        match s.marker {
            Marker::None => {}
            Marker::Circle => area.draw(&Circle::new(at, 3, filled)).map_err(err)?,
            Marker::Triangle => area
                .draw(&TriangleMarker::new(at, 4, filled))
                .map_err(err)?,
            Marker::Square => area
                .draw(&Rectangle::new([(12, y - 3), (18, y + 3)], filled))
                .map_err(err)?,
            Marker::Cross => area
                .draw(&Cross::new(at, 4, s.color.stroke_width(2)))
                .map_err(err)?,
        }
        area.draw(&Text::new(s.label.clone(), (32, y - 6), font.clone()))
            .map_err(err)?;
    }
    Ok(())
}

fn draw<X>(
    root: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    plot: &Plot,
    x: X,
    y: Range<f64>,
) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
{
    let err = |e: DrawingAreaErrorKind<_>| anyhow!("{e:?}");
    let (y_lo, y_hi) = (y.start, y.end);
    let mut chart = ChartBuilder::on(root)
        .caption(&plot.title, ("sans-serif", 20))
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
        let filled = color.filled();
        match s.marker {
            Marker::None => {}
            Marker::Circle => {
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 3, filled)))
                    .map_err(err)?;
            }
            Marker::Triangle => {
                chart
                    .draw_series(pts.iter().map(|&p| TriangleMarker::new(p, 4, filled)))
                    .map_err(err)?;
            }
            Marker::Square => {
                chart
                    .draw_series(
                        pts.iter().map(|&p| {
                            EmptyElement::at(p) + Rectangle::new([(-3, -3), (3, 3)], filled)
                        }),
                    )
                    .map_err(err)?;
            }
            Marker::Cross => {
                chart
                    .draw_series(pts.iter().map(|&p| Cross::new(p, 4, color.stroke_width(2))))
                    .map_err(err)?;
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
