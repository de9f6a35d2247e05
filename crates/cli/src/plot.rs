//! Figures: line and scatter plots written as PNG or SVG (chosen by the file extension), with
//! an embedded font so they render on machines without system fonts.

use anyhow::{Context, Result, bail};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// Registers the embedded DejaVu Sans as plotters' `sans-serif` (once).
fn register_font() {
    REGISTER.call_once(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| ())
            .expect("the embedded font is a valid TTF");
    });
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Style {
    /// A polyline through the points.
    Line,
    /// A dot per point (scatter plots of the experiments).
    #[allow(dead_code)]
    Points,
}

/// One data series.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// `(x, y)` points.
    pub points: Vec<(f64, f64)>,
    /// Colour.
    pub color: RGBColor,
    /// Line or points.
    pub style: Style,
}

/// A figure's axes and options.
#[derive(Clone, Debug)]
pub struct Figure<'a> {
    /// Title above the plot.
    pub title: &'a str,
    /// Label of the x axis.
    pub x_label: &'a str,
    /// Label of the y axis.
    pub y_label: &'a str,
    /// Equal scale on both axes (for top views of trajectories).
    pub equal_aspect: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
}

/// A palette of distinguishable colours.
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Grey for reference data (e.g. initial or ground-truth trajectories).
pub const GREY: RGBColor = RGBColor(150, 150, 150);

/// Draws `series` into `path` (`.png` or `.svg`), 1000×800 pixels.
pub fn plot(path: &Path, figure: &Figure, series: &[Series]) -> Result<()> {
    register_font();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("png") => {
            let root = BitMapBackend::new(path, (1000, 800)).into_drawing_area();
            draw(&root, figure, series)?;
            root.present()
                .with_context(|| format!("writing {}", path.display()))?;
        }
        Some("svg") => {
            let root = SVGBackend::new(path, (1000, 800)).into_drawing_area();
            draw(&root, figure, series)?;
            root.present()
                .with_context(|| format!("writing {}", path.display()))?;
        }
        _ => bail!("{}: plots are written as .png or .svg", path.display()),
    }
    Ok(())
}

fn bounds(series: &[Series], log_y: bool) -> Option<(f64, f64, f64, f64)> {
    let mut it = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| x.is_finite() && y.is_finite() && (!log_y || *y > 0.0));
    let first = it.next()?;
    let (mut x0, mut x1, mut y0, mut y1) = (first.0, first.0, first.1, first.1);
    for &(x, y) in it {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    Some((x0, x1, y0, y1))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    figure: &Figure,
    series: &[Series],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (mut x0, mut x1, mut y0, mut y1) =
        bounds(series, figure.log_y).unwrap_or((0.0, 1.0, 0.0, 1.0));
    if x1 - x0 <= 0.0 {
        x0 -= 0.5;
        x1 += 0.5;
    }
    if y1 - y0 <= 0.0 {
        let pad = if figure.log_y { y0 * 0.5 } else { 0.5 };
        y0 -= pad;
        y1 += pad;
    }
    if figure.equal_aspect {
        // Plot area is about 5:4; widen the narrower range around its centre.
        let (w, h) = (x1 - x0, y1 - y0);
        let aspect = 1.25;
        if w / h < aspect {
            let c = 0.5 * (x0 + x1);
            x0 = c - 0.5 * h * aspect;
            x1 = c + 0.5 * h * aspect;
        } else {
            let c = 0.5 * (y0 + y1);
            y0 = c - 0.5 * w / aspect;
            y1 = c + 0.5 * w / aspect;
        }
    }
    let (mx, my) = (0.03 * (x1 - x0), 0.03 * (y1 - y0));
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(figure.title, ("sans-serif", 28))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(80);
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(figure.x_label)
                .y_desc(figure.y_label)
                .label_style(("sans-serif", 16))
                .axis_desc_style(("sans-serif", 18))
                .draw()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            for s in series {
                let color = s.color;
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(x, y)| x.is_finite() && y.is_finite() && (!figure.log_y || *y > 0.0))
                    .collect();
                let anno = match s.style {
                    Style::Line => chart
                        .draw_series(LineSeries::new(pts, color.stroke_width(2)))
                        .map_err(|e| anyhow::anyhow!("{e:?}"))?,
                    Style::Points => chart
                        .draw_series(pts.into_iter().map(|p| Circle::new(p, 2, color.filled())))
                        .map_err(|e| anyhow::anyhow!("{e:?}"))?,
                };
                if !s.label.is_empty() {
                    anno.label(s.label.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3))
                    });
                }
            }
            if series.iter().any(|s| !s.label.is_empty()) {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 16))
                    .draw()
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            }
        }};
    }
    if figure.log_y {
        finish!(
            builder
                .build_cartesian_2d(x0 - mx..x1 + mx, (y0 * 0.8..y1 * 1.25).log_scale())
                .map_err(|e| anyhow::anyhow!("{e:?}"))?
        );
    } else {
        finish!(
            builder
                .build_cartesian_2d(x0 - mx..x1 + mx, y0 - my..y1 + my)
                .map_err(|e| anyhow::anyhow!("{e:?}"))?
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg_and_refuses_other_formats() {
        let dir = std::env::temp_dir().join(format!("dwslam-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let series = vec![
            Series {
                label: "line".into(),
                points: (0..50)
                    .map(|i| (i as f64, (i as f64 * 0.2).sin()))
                    .collect(),
                color: PALETTE[0],
                style: Style::Line,
            },
            Series {
                label: "dots".into(),
                points: (0..50)
                    .map(|i| (i as f64, (i as f64 * 0.2).cos()))
                    .collect(),
                color: PALETTE[1],
                style: Style::Points,
            },
        ];
        let fig = Figure {
            title: "test",
            x_label: "x",
            y_label: "y",
            equal_aspect: false,
            log_y: false,
        };
        for name in ["a.png", "a.svg"] {
            let path = dir.join(name);
            plot(&path, &fig, &series).unwrap();
            assert!(std::fs::metadata(&path).unwrap().len() > 1000);
        }
        // A PNG with text drawn has many distinct non-white pixels in the title row band.
        let svg = std::fs::read_to_string(dir.join("a.svg")).unwrap();
        assert!(svg.contains("test"));
        assert!(plot(&dir.join("a.jpg"), &fig, &series).is_err());
        let log_fig = Figure { log_y: true, ..fig };
        plot(&dir.join("log.png"), &log_fig, &series).unwrap();
        std::fs::remove_dir_all(&dir).ok();
    }
}
