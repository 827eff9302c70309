//! Study charts with `plotters`, each written as SVG and PNG.
//!
//! Text is laid out and rasterised with `ab_glyph` from a font compiled into the binary
//! (`assets/fonts/DejaVuSans-subset.ttf`, registered as `sans-serif`), so charts render the same
//! on a machine without system fonts. The SVG files name the font family `sans-serif` and leave
//! drawing the text to the viewer.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use plotters::style::FontStyle;

use super::table::series_by;
use super::{RunOutcome, RunRecord};

const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-subset.ttf");
const SIZE: (u32, u32) = (960, 640);

/// Tableau-10 colours, then six darker ones for studies with more series (Fig. 3 has 12);
/// `usize::MAX` is black (a reference curve).
const PALETTE: [(u8, u8, u8); 16] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
    (128, 0, 0),
    (0, 0, 128),
    (0, 128, 128),
    (128, 128, 0),
    (190, 0, 190),
    (60, 60, 60),
];

fn colour(index: usize) -> RGBColor {
    if index == usize::MAX {
        BLACK
    } else {
        let (r, g, b) = PALETTE[index % PALETTE.len()];
        RGBColor(r, g, b)
    }
}

fn register_font() -> Result<(), String> {
    static ONCE: Once = Once::new();
    let mut result = Ok(());
    ONCE.call_once(|| {
        result = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| "the bundled chart font is not a valid font".to_string());
    });
    result
}

/// One curve of a chart.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// Palette index (`usize::MAX` = black).
    pub color: usize,
    pub dashed: bool,
    pub markers: bool,
    pub line: bool,
}

/// A tick label: plain for moderate magnitudes, `1e-4` style otherwise.
fn tick(value: &f64) -> String {
    let a = value.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{value:.0e}")
    } else {
        let text = format!("{value:.4}");
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// The axis range over `values`: padded by a factor (log) or 5% (linear).
fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { (0.1, 10.0) } else { (0.0, 1.0) };
    }
    if log {
        // Whole decades, so that a log axis always has labelled powers of ten.
        let lo = 10f64.powf((lo.log10() + 1e-9).floor());
        let hi = 10f64.powf((hi.log10() - 1e-9).ceil());
        (lo, if hi > lo { hi } else { 10.0 * lo })
    } else if hi <= lo {
        (lo - 1.0, hi + 1.0)
    } else {
        let pad = 0.05 * (hi - lo);
        (lo - pad, hi + pad)
    }
}

/// Draws `series` on `root` with the given axis specs.
fn draw<DB, X, Y>(
    root: DrawingArea<DB, Shift>,
    series: &[Series],
    labels: (&str, &str),
    legend: &SeriesLabelPosition,
    x_spec: X,
    y_spec: Y,
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(80)
        .build_cartesian_2d(x_spec, y_spec)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(labels.0)
        .y_desc(labels.1)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .draw()
        .map_err(err)?;
    for s in series {
        let style = ShapeStyle::from(&colour(s.color)).stroke_width(2);
        if s.line && s.dashed {
            chart
                .draw_series(DashedLineSeries::new(s.points.clone(), 8, 6, style))
                .map_err(err)?
                .label(&s.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 10, y)], style));
        } else if s.line {
            chart
                .draw_series(LineSeries::new(s.points.clone(), style))
                .map_err(err)?
                .label(&s.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        if s.markers {
            let fill = style.filled();
            let annotation = chart
                .draw_series(s.points.iter().map(|&(x, y)| Circle::new((x, y), 3, fill)))
                .map_err(err)?;
            if !s.line {
                annotation
                    .label(&s.label)
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, fill));
            }
        }
    }
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(legend.clone())
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// Draws on one backend with linear or logarithmic axes.
fn draw_axes<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    series: &[Series],
    labels: (&str, &str),
    log: (bool, bool),
    legend: &SeriesLabelPosition,
) -> Result<(), String> {
    let all = || series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = range(all().map(|p| p.0), log.0);
    let (y0, y1) = range(all().map(|p| p.1), log.1);
    match log {
        (true, true) => draw(
            root,
            series,
            labels,
            legend,
            (x0..x1).log_scale(),
            (y0..y1).log_scale(),
        ),
        (true, false) => draw(root, series, labels, legend, (x0..x1).log_scale(), y0..y1),
        (false, true) => draw(root, series, labels, legend, x0..x1, (y0..y1).log_scale()),
        (false, false) => draw(root, series, labels, legend, x0..x1, y0..y1),
    }
}

/// Writes `<stem>.svg` and `<stem>.png`: `series` with logarithmic axes where `log` says so
/// (`(x, y)`), the legend at `legend`; points that a log axis cannot show (<= 0) are dropped.
pub fn chart(
    series: &[Series],
    x_label: &str,
    y_label: &str,
    log: (bool, bool),
    legend: SeriesLabelPosition,
    stem: &Path,
) -> Result<(), String> {
    register_font()?;
    let visible: Vec<Series> = series
        .iter()
        .map(|s| Series {
            points: s
                .points
                .iter()
                .copied()
                .filter(|(x, y)| {
                    x.is_finite() && y.is_finite() && (!log.0 || *x > 0.0) && (!log.1 || *y > 0.0)
                })
                .collect(),
            ..s.clone()
        })
        .filter(|s| !s.points.is_empty())
        .collect();
    let svg = stem.with_extension("svg");
    let png = stem.with_extension("png");
    let labels = (x_label, y_label);
    draw_axes(
        SVGBackend::new(&svg, SIZE).into_drawing_area(),
        &visible,
        labels,
        log,
        &legend,
    )
    .map_err(|e| format!("{}: {e}", svg.display()))?;
    draw_axes(
        BitMapBackend::new(&png, SIZE).into_drawing_area(),
        &visible,
        labels,
        log,
        &legend,
    )
    .map_err(|e| format!("{}: {e}", png.display()))
}

/// One series per combination of the other swept parameters: raw error solid with markers,
/// recovered error dashed in the same colour.
fn error_series(
    records: &[RunRecord],
    against: &str,
    x: impl Fn(&RunRecord) -> f64,
) -> Vec<Series> {
    let mut out = Vec::new();
    for (k, (label, _, _)) in series_by(records, against).into_iter().enumerate() {
        let members: Vec<&RunRecord> = records
            .iter()
            .filter(|r| r.outcome == RunOutcome::Completed && r.label_without(against) == label)
            .filter(|r| {
                r.parameter(against)
                    .is_some_and(|v| v.parse::<f64>().is_ok())
            })
            .collect();
        let order = |r: &&RunRecord| {
            r.parameter(against)
                .and_then(|v| v.parse::<f64>().ok())
                .unwrap_or(0.0)
        };
        let mut sorted = members.clone();
        sorted.sort_by(|a, b| order(a).total_cmp(&order(b)));
        let name = if label.is_empty() {
            "error".to_string()
        } else {
            label
        };
        let raw: Vec<(f64, f64)> = sorted
            .iter()
            .filter_map(|r| Some((x(r), r.error?)))
            .collect();
        let recovered: Vec<(f64, f64)> = sorted
            .iter()
            .filter_map(|r| Some((x(r), r.error_recovered?)))
            .collect();
        if !raw.is_empty() {
            out.push(Series {
                label: name.clone(),
                points: raw,
                color: k,
                dashed: false,
                markers: true,
                line: true,
            });
        }
        if !recovered.is_empty() {
            out.push(Series {
                label: format!("{name} (recovered)"),
                points: recovered,
                color: k,
                dashed: true,
                markers: false,
                line: true,
            });
        }
    }
    out
}

/// `error_vs_<against>.svg/.png`.
pub fn error_against_parameter(
    records: &[RunRecord],
    against: &str,
    measure: &str,
    stem: &Path,
) -> Result<(), String> {
    let x = |r: &RunRecord| {
        r.parameter(against)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    chart(
        &error_series(records, against, x),
        against,
        measure,
        (true, true),
        SeriesLabelPosition::UpperRight,
        stem,
    )
}

/// `error_vs_time.svg/.png`: the accuracy-cost front. Series as in the error chart (joined in
/// the order of `against`), or one point per run if no numeric parameter is swept.
pub fn error_against_time(
    records: &[RunRecord],
    against: Option<&str>,
    measure: &str,
    stem: &Path,
) -> Result<(), String> {
    let series = match against {
        Some(against) => error_series(records, against, |r| r.wall_seconds),
        None => records
            .iter()
            .filter(|r| r.outcome == RunOutcome::Completed)
            .enumerate()
            .filter_map(|(k, r)| {
                Some(Series {
                    label: r.label_without(""),
                    points: vec![(r.wall_seconds, r.error?)],
                    color: k,
                    dashed: false,
                    markers: true,
                    line: false,
                })
            })
            .collect(),
    };
    chart(
        &series,
        "wall time per run [s]",
        measure,
        (true, true),
        SeriesLabelPosition::UpperRight,
        stem,
    )
}
