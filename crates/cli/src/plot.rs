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
    /// A polyline through the points, broken where a point is not finite.
    Line,
    /// A dot per point (scatter plots of the experiments).
    Points,
    /// A ring per point: a few events marked on other series (e.g. relocalisations).
    Markers,
    /// A dashed polyline (a second family of curves beside `Line`), broken like `Line`.
    Dashed,
    /// Separate line segments: points `2i` and `2i + 1` joined (graph edges).
    Segments,
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

/// Renders into `path` (`.png` or `.svg`, 1000×800 pixels) with `$draw` called on the root
/// drawing area of the backend the extension names (a macro: the two backends are different
/// types).
macro_rules! render {
    ($path:expr, |$root:ident| $draw:expr) => {{
        let path: &Path = $path;
        register_font();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("png") => {
                let $root = &BitMapBackend::new(path, (1000, 800)).into_drawing_area();
                $draw?;
                $root
                    .present()
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            Some("svg") => {
                let $root = &SVGBackend::new(path, (1000, 800)).into_drawing_area();
                $draw?;
                $root
                    .present()
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            _ => bail!("{}: plots are written as .png or .svg", path.display()),
        }
        Ok(())
    }};
}

/// Draws `series` into `path` (`.png` or `.svg`), 1000×800 pixels.
pub fn plot(path: &Path, figure: &Figure, series: &[Series]) -> Result<()> {
    render!(path, |root| draw(root, figure, series))
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

/// The corner of the plot where the legend hides the fewest points: of the four corner boxes
/// (45 % of the width, 30 % of the height), the one holding the fewest; upper right on a tie.
fn legend_corner(
    series: &[Series],
    (x0, x1, y0, y1): (f64, f64, f64, f64),
    log_y: bool,
) -> SeriesLabelPosition {
    let y_of = |y: f64| {
        if log_y {
            y.max(f64::MIN_POSITIVE).log10()
        } else {
            y
        }
    };
    let (ya, yb) = (y_of(y0), y_of(y1));
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let count = |right: bool, upper: bool| {
        series
            .iter()
            .flat_map(|s| &s.points)
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .filter(|&&(x, y)| {
                let fx = (x - x0) / (x1 - x0);
                let fy = (y_of(y) - ya) / (yb - ya);
                (if right { fx > 0.55 } else { fx < 0.45 })
                    && (if upper { fy > 0.7 } else { fy < 0.3 })
            })
            .count()
    };
    corners
        .into_iter()
        .min_by_key(|&(_, right, upper)| count(right, upper))
        .map_or(SeriesLabelPosition::UpperRight, |(p, _, _)| p)
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
                .y_label_formatter(&|v: &f64| significant(*v))
                .draw()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            for s in series {
                let color = s.color;
                // A polyline breaks where a point is not finite (a gap: frames without a pose).
                let keep = |&(x, y): &(f64, f64)| {
                    x.is_finite() && y.is_finite() && (!figure.log_y || y > 0.0)
                };
                let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
                for p in &s.points {
                    match (keep(p), runs.last_mut()) {
                        (true, Some(run)) => run.push(*p),
                        (false, Some(run)) if !run.is_empty() => runs.push(Vec::new()),
                        _ => {}
                    }
                }
                runs.retain(|r| !r.is_empty());
                let pts: Vec<(f64, f64)> = runs.concat();
                let anno = match s.style {
                    Style::Line => {
                        let last = runs.pop().unwrap_or_default();
                        for r in runs {
                            chart
                                .draw_series(LineSeries::new(r, color.stroke_width(2)))
                                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
                        }
                        chart
                            .draw_series(LineSeries::new(last, color.stroke_width(2)))
                            .map_err(|e| anyhow::anyhow!("{e:?}"))?
                    }
                    Style::Points => chart
                        .draw_series(pts.into_iter().map(|p| Circle::new(p, 2, color.filled())))
                        .map_err(|e| anyhow::anyhow!("{e:?}"))?,
                    Style::Markers => chart
                        .draw_series(
                            pts.into_iter()
                                .map(|p| Circle::new(p, 7, color.stroke_width(3))),
                        )
                        .map_err(|e| anyhow::anyhow!("{e:?}"))?,
                    Style::Dashed => {
                        let last = runs.pop().unwrap_or_default();
                        for r in runs {
                            chart
                                .draw_series(DashedLineSeries::new(r, 8, 6, color.stroke_width(2)))
                                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
                        }
                        chart
                            .draw_series(DashedLineSeries::new(last, 8, 6, color.stroke_width(2)))
                            .map_err(|e| anyhow::anyhow!("{e:?}"))?
                    }
                    Style::Segments => chart
                        .draw_series(
                            s.points
                                .chunks_exact(2)
                                .filter(|c| c.iter().all(|(x, y)| x.is_finite() && y.is_finite()))
                                .map(|c| PathElement::new(vec![c[0], c[1]], color.stroke_width(1))),
                        )
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
                    .position(legend_corner(series, (x0, x1, y0, y1), figure.log_y))
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

/// A heat map: values on a grid of cells, drawn as coloured rectangles with the grid's values
/// as tick labels (the axes may be irregular, e.g. `N` doubling) and a colour bar.
#[derive(Clone, Debug)]
pub struct HeatMap<'a> {
    /// Title above the plot.
    pub title: &'a str,
    /// Label of the x axis.
    pub x_label: &'a str,
    /// Label of the y axis.
    pub y_label: &'a str,
    /// Label of the colour bar.
    pub value_label: &'a str,
    /// Column values (x), in order.
    pub x_values: &'a [f64],
    /// Row values (y), in order.
    pub y_values: &'a [f64],
    /// `values[row * x_values.len() + column]`; non-finite cells are left blank.
    pub values: &'a [f64],
    /// Write each cell's value into it.
    pub annotate: bool,
}

/// A perceptually ordered colour map (viridis, piecewise linear through 6 anchors) for
/// `t ∈ [0, 1]`.
pub fn viridis(t: f64) -> RGBColor {
    const ANCHORS: [(f64, f64, f64); 6] = [
        (68.0, 1.0, 84.0),
        (65.0, 68.0, 135.0),
        (42.0, 120.0, 142.0),
        (34.0, 168.0, 132.0),
        (122.0, 209.0, 81.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (ANCHORS.len() - 1) as f64;
    let k = (x.floor() as usize).min(ANCHORS.len() - 2);
    let f = x - k as f64;
    let (a, b) = (ANCHORS[k], ANCHORS[k + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// `v` to three significant digits without trailing zeros (tick labels: log-scale ticks such
/// as `0.010000000001` print as `0.01`).
fn significant(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor();
    if !(-3.0..5.0).contains(&magnitude) {
        return format!("{v:.2e}");
    }
    let decimals = (2.0 - magnitude).max(0.0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn format_tick(v: f64) -> String {
    if v == v.round() && v.abs() < 1e6 {
        format!("{}", v as i64)
    } else {
        format!("{v:.3}")
    }
}

/// Draws a heat map into `path` (`.png` or `.svg`), 1000×800 pixels.
pub fn heatmap(path: &Path, map: &HeatMap) -> Result<()> {
    let (nx, ny) = (map.x_values.len(), map.y_values.len());
    if nx * ny != map.values.len() || nx == 0 || ny == 0 {
        bail!(
            "heat map {}: {} values for a {nx}×{ny} grid",
            path.display(),
            map.values.len()
        );
    }
    render!(path, |root| draw_heatmap(root, map))
}

fn draw_heatmap<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, map: &HeatMap) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e:?}");
    root.fill(&WHITE).map_err(err)?;
    let (nx, ny) = (map.x_values.len(), map.y_values.len());
    let finite: Vec<f64> = map
        .values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let (lo, hi) = finite
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let (lo, hi) = if lo.is_finite() && hi > lo {
        (lo, hi)
    } else if lo.is_finite() {
        (lo - 0.5, lo + 0.5)
    } else {
        (0.0, 1.0)
    };
    let (main, bar) = root.split_horizontally(860);
    let mut chart = ChartBuilder::on(&main)
        .caption(map.title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(-0.5..nx as f64 - 0.5, -0.5..ny as f64 - 0.5)
        .map_err(err)?;
    let xv = map.x_values.to_vec();
    let yv = map.y_values.to_vec();
    let x_fmt = move |v: &f64| {
        let k = v.round();
        if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < xv.len() {
            format_tick(xv[k as usize])
        } else {
            String::new()
        }
    };
    let y_fmt = move |v: &f64| {
        let k = v.round();
        if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < yv.len() {
            format_tick(yv[k as usize])
        } else {
            String::new()
        }
    };
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(nx.min(40))
        .y_labels(ny.min(40))
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .x_desc(map.x_label)
        .y_desc(map.y_label)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 18))
        .draw()
        .map_err(err)?;
    let color = |v: f64| viridis((v - lo) / (hi - lo));
    chart
        .draw_series(
            (0..ny)
                .flat_map(|r| (0..nx).map(move |c| (r, c)))
                .filter_map(|(r, c)| {
                    let v = map.values[r * nx + c];
                    v.is_finite().then(|| {
                        Rectangle::new(
                            [
                                (c as f64 - 0.5, r as f64 - 0.5),
                                (c as f64 + 0.5, r as f64 + 0.5),
                            ],
                            color(v).filled(),
                        )
                    })
                }),
        )
        .map_err(err)?;
    if map.annotate {
        for r in 0..ny {
            for c in 0..nx {
                let v = map.values[r * nx + c];
                if !v.is_finite() {
                    continue;
                }
                let t = (v - lo) / (hi - lo);
                let text_color = if t > 0.6 { BLACK } else { WHITE };
                chart
                    .draw_series(std::iter::once(Text::new(
                        format!("{v:.2}"),
                        (c as f64 - 0.3, r as f64 + 0.1),
                        ("sans-serif", 13).into_font().color(&text_color),
                    )))
                    .map_err(err)?;
            }
        }
    }
    // Colour bar.
    let mut bar_chart = ChartBuilder::on(&bar)
        .margin_top(60)
        .margin_bottom(70)
        .margin_right(10)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(err)?;
    bar_chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(map.value_label)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .draw()
        .map_err(err)?;
    let steps = 100;
    bar_chart
        .draw_series((0..steps).map(|k| {
            let (a, b) = (
                lo + (hi - lo) * k as f64 / steps as f64,
                lo + (hi - lo) * (k + 1) as f64 / steps as f64,
            );
            Rectangle::new([(0.0, a), (1.0, b)], color(0.5 * (a + b)).filled())
        }))
        .map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The legend goes to the emptiest corner: with the data in the upper half (the right
    /// upper corner fullest), not the default upper right; with nothing anywhere, upper right.
    #[test]
    fn the_legend_takes_the_emptiest_corner() {
        let series = |points: Vec<(f64, f64)>| Series {
            label: "s".into(),
            points,
            color: BLACK,
            style: Style::Points,
        };
        let upper: Vec<(f64, f64)> = (0..100)
            .map(|i| (i as f64 / 100.0, 0.8 + 0.2 * (i % 7) as f64 / 7.0))
            .chain((0..20).map(|i| (0.9, 0.75 + 0.01 * i as f64)))
            .collect();
        let bounds = (0.0, 1.0, 0.0, 1.0);
        let corner = legend_corner(&[series(upper)], bounds, false);
        assert!(
            matches!(
                corner,
                SeriesLabelPosition::LowerLeft | SeriesLabelPosition::LowerRight
            ),
            "{corner:?}"
        );
        let lower_left: Vec<(f64, f64)> = vec![(0.1, 0.1), (0.2, 0.2), (0.9, 0.1), (0.1, 0.9)];
        let corner = legend_corner(&[series(lower_left)], bounds, false);
        assert!(
            matches!(corner, SeriesLabelPosition::UpperRight),
            "{corner:?}"
        );
        // NaN breaks are not points.
        let corner = legend_corner(&[series(vec![(f64::NAN, f64::NAN)])], bounds, false);
        assert!(
            matches!(corner, SeriesLabelPosition::UpperRight),
            "{corner:?}"
        );
    }

    #[test]
    fn significant_digits_trim_floating_point_noise() {
        assert_eq!(significant(0.010000000001), "0.01");
        assert_eq!(significant(0.00234567), "0.00235");
        assert_eq!(significant(1500.0), "1500");
        assert_eq!(significant(2.5), "2.5");
        assert_eq!(significant(-0.5), "-0.5");
        assert_eq!(significant(0.0), "0");
        assert_eq!(significant(1.5e-6), "1.50e-6");
    }

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
        let values = [1.0, 2.0, f64::NAN, 4.0, 5.0, 6.0];
        let map = HeatMap {
            title: "heat",
            x_label: "x",
            y_label: "y",
            value_label: "v",
            x_values: &[1.0, 2.0, 4.0],
            y_values: &[15.0, 30.0],
            values: &values,
            annotate: true,
        };
        heatmap(&dir.join("heat.png"), &map).unwrap();
        heatmap(&dir.join("heat.svg"), &map).unwrap();
        assert!(
            std::fs::read_to_string(dir.join("heat.svg"))
                .unwrap()
                .contains("heat")
        );
        assert!(
            heatmap(
                &dir.join("bad.png"),
                &HeatMap {
                    values: &values[..5],
                    ..map
                }
            )
            .is_err()
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
