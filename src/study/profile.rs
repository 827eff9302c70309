//! Stress profiles along the column (`impm study --profiles`): the final state of every run,
//! read back from its `particles_NNNN.vtu` as ParaView would, against the analytic solution.
//!
//! For each point: the reference coordinate `X` along the column axis, the normal Cauchy
//! stress `σ` along that axis (raw, and recovered when the file has `recovered_stress`) and the
//! semi-analytic `σ_A(X)` (paper eq. 11) when the scene declares the column. The error chart
//! shows `|σ − σ_A| / W` on a log axis, where `W` is the base stress, so one can see where along
//! the column the error lives.

use std::fmt::Write as _;
use std::path::Path;

use plotters::chart::SeriesLabelPosition;

use super::plot::{Series, chart};
use super::{RunOutcome, RunRecord};
use crate::analytic::SelfWeightColumn;
use crate::output::read_vtu;
use crate::scene::AnalyticSpec;

/// One material point of a final profile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProfilePoint {
    /// Reference coordinate along the column axis.
    pub reference: f64,
    pub stress: f64,
    pub recovered: Option<f64>,
    pub analytic: Option<f64>,
    /// The base stress `W` of the analytic solution (for relative errors).
    pub weight: Option<f64>,
}

/// Reads the `axis`-normal stress of every point of a `particles_NNNN.vtu`, sorted by the
/// reference coordinate, with the analytic stress at load factor `factor` if declared.
pub fn read_profile(
    file: &Path,
    axis: usize,
    analytic: Option<&AnalyticSpec>,
    factor: f64,
) -> Result<Vec<ProfilePoint>, String> {
    let contents = read_vtu(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let field = |name: &str, components: usize| -> Result<&[f64], String> {
        match contents.point_field(name) {
            Some((c, values)) if c == components => Ok(values),
            _ => Err(format!(
                "{}: no {components}-component field '{name}'",
                file.display()
            )),
        }
    };
    let reference = field("reference_position", 3)?;
    let stress = field("cauchy_stress", 9)?;
    let recovered = field("recovered_stress", 9).ok();
    let column = analytic.map(|a| match *a {
        AnalyticSpec::Column {
            height,
            density,
            body_force,
            modulus,
            ..
        } => SelfWeightColumn {
            density,
            body_force: body_force * factor,
            height,
            modulus,
        },
    });
    let component = 3 * axis + axis;
    let mut profile: Vec<ProfilePoint> = (0..contents.points.len())
        .map(|p| {
            let x = reference[3 * p + axis];
            ProfilePoint {
                reference: x,
                stress: stress[9 * p + component],
                recovered: recovered.map(|r| r[9 * p + component]),
                analytic: column.map(|c| c.stress(x)),
                weight: column.map(|c| c.weight()),
            }
        })
        .collect();
    profile.sort_by(|a, b| a.reference.total_cmp(&b.reference));
    Ok(profile)
}

fn cell(value: Option<f64>) -> String {
    value.map(|v| format!("{v:e}")).unwrap_or_default()
}

/// `profiles.csv`: `index,<swept names>,reference,stress,recovered,analytic`.
pub fn csv(names: &[String], records: &[RunRecord]) -> String {
    let mut out = String::from("index");
    for n in names {
        out += &format!(",{n}");
    }
    out += ",reference,stress,recovered,analytic\n";
    for r in records {
        let parameters: String = names
            .iter()
            .map(|n| format!(",{}", r.parameter(n).unwrap_or_default()))
            .collect();
        for p in &r.profile {
            let _ = writeln!(
                out,
                "{}{parameters},{:e},{:e},{},{}",
                r.index,
                p.reference,
                p.stress,
                cell(p.recovered),
                cell(p.analytic)
            );
        }
    }
    out
}

/// `profiles.svg/.png` (stress against X, analytic as a line) and `profile_errors.svg/.png`
/// (`|σ − σ_A| / W` against X, log axis; recovered dashed).
pub fn charts(records: &[RunRecord], dir: &Path) -> Result<(), String> {
    let completed: Vec<&RunRecord> = records
        .iter()
        .filter(|r| r.outcome == RunOutcome::Completed && !r.profile.is_empty())
        .collect();
    let label = |r: &RunRecord| {
        let l = r.label_without("");
        if l.is_empty() { "run".to_string() } else { l }
    };
    let mut stress_series = Vec::new();
    let mut error_series = Vec::new();
    for (k, r) in completed.iter().enumerate() {
        stress_series.push(Series {
            label: label(r),
            points: r.profile.iter().map(|p| (p.reference, p.stress)).collect(),
            color: k,
            dashed: false,
            markers: true,
            line: false,
        });
        let relative = |value: f64, p: &ProfilePoint| -> Option<(f64, f64)> {
            let (a, w) = (p.analytic?, p.weight?);
            let e = (value - a).abs() / w;
            (e > 0.0).then_some((p.reference, e))
        };
        let raw: Vec<(f64, f64)> = r
            .profile
            .iter()
            .filter_map(|p| relative(p.stress, p))
            .collect();
        if !raw.is_empty() {
            error_series.push(Series {
                label: label(r),
                points: raw,
                color: k,
                dashed: false,
                markers: true,
                line: true,
            });
        }
        let recovered: Vec<(f64, f64)> = r
            .profile
            .iter()
            .filter_map(|p| relative(p.recovered?, p))
            .collect();
        if !recovered.is_empty() {
            error_series.push(Series {
                label: format!("{} (recovered)", label(r)),
                points: recovered,
                color: k,
                dashed: true,
                markers: false,
                line: true,
            });
        }
    }
    // The analytic stress along the longest profile, as a black line.
    if let Some(longest) = completed.iter().max_by_key(|r| r.profile.len()) {
        let analytic: Vec<(f64, f64)> = longest
            .profile
            .iter()
            .filter_map(|p| Some((p.reference, p.analytic?)))
            .collect();
        if !analytic.is_empty() {
            stress_series.push(Series {
                label: "semi-analytic".into(),
                points: analytic,
                color: usize::MAX,
                dashed: false,
                markers: false,
                line: true,
            });
        }
    }
    chart(
        &stress_series,
        "reference position X along the column",
        "Cauchy stress along the column",
        (false, false),
        SeriesLabelPosition::UpperLeft,
        &dir.join("profiles"),
    )?;
    chart(
        &error_series,
        "reference position X along the column",
        "|stress - analytic| / W",
        (false, true),
        SeriesLabelPosition::LowerMiddle,
        &dir.join("profile_errors"),
    )
}
