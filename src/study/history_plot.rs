//! `impm plot OUT_DIR --x NAME --y NAME[,NAME..]`: a chart of columns of a run's `history.csv`
//! (e.g. a load–settlement curve), written as `OUT_DIR/history_<x>_<y>.svg` and `.png` with the
//! study charts' plotters code (`plot::chart`).

use std::path::{Path, PathBuf};

use plotters::prelude::SeriesLabelPosition;

use super::plot::{Series, chart};

/// The columns of a `history.csv` text: names and values (an empty cell is NaN).
pub fn read_history(text: &str) -> Result<(Vec<String>, Vec<Vec<f64>>), String> {
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<String> = lines
        .next()
        .ok_or("history.csv is empty")?
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    let mut columns = vec![Vec::new(); header.len()];
    for (row, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != header.len() {
            return Err(format!(
                "history.csv row {} has {} values for {} columns",
                row + 1,
                cells.len(),
                header.len()
            ));
        }
        for (column, cell) in columns.iter_mut().zip(cells) {
            let cell = cell.trim();
            column.push(if cell.is_empty() {
                f64::NAN
            } else {
                cell.parse()
                    .map_err(|_| format!("history.csv row {}: '{cell}' is not a number", row + 1))?
            });
        }
    }
    Ok((header, columns))
}

/// Draws `ys` against `x` from `out_dir/history.csv`; returns the chart's path stem.
pub fn plot_history(out_dir: &Path, x: &str, ys: &[String]) -> Result<PathBuf, String> {
    let path = out_dir.join("history.csv");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (names, columns) = read_history(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let column = |name: &str| {
        names
            .iter()
            .position(|n| n == name)
            .map(|i| &columns[i])
            .ok_or_else(|| {
                format!(
                    "{} has no column '{name}'; its columns are: {}",
                    path.display(),
                    names.join(", ")
                )
            })
    };
    if ys.is_empty() {
        return Err("give at least one column to --y".into());
    }
    let xs = column(x)?;
    let mut series = Vec::new();
    for (index, y) in ys.iter().enumerate() {
        let values = column(y)?;
        series.push(Series {
            label: y.clone(),
            points: xs.iter().copied().zip(values.iter().copied()).collect(),
            color: index,
            dashed: false,
            markers: true,
            line: true,
        });
    }
    if series.iter().all(|s| {
        s.points
            .iter()
            .all(|(a, b)| !a.is_finite() || !b.is_finite())
    }) {
        return Err(format!(
            "{}: the columns {x} and {} have no values to draw",
            path.display(),
            ys.join(", ")
        ));
    }
    let stem = out_dir.join(format!("history_{x}_{}", ys.join("_")));
    chart(
        &series,
        x,
        &ys.join(", "),
        (false, false),
        SeriesLabelPosition::UpperLeft,
        &stem,
    )?;
    Ok(stem)
}
