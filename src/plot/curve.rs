//! Reading a run's `curve.csv` (written by [`crate::run_dir::Curve`]) back as points: the
//! header names the columns, each row is one evaluation, and every problem names the file and
//! the line.

use crate::error::{Error, Result};
use std::path::Path;

/// Largest `curve.csv` read (about half a million rows): a bigger file is not a curve.
pub const MAX_CURVE_BYTES: u64 = 16 << 20;

/// The columns a curve must have (in any order; others are ignored).
pub const COLUMNS: [&str; 4] = ["step", "minutes", "train_psnr", "val_psnr"];

/// One row of `curve.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurvePoint {
    /// Steps done.
    pub step: usize,
    /// Minutes of training (across resumes).
    pub minutes: f64,
    /// Mean training-batch PSNR (dB) over the last batches.
    pub train_psnr: f32,
    /// The quick validation PSNR (dB); `None` on rows without one (a run without val views).
    pub val_psnr: Option<f32>,
}

/// Read `path` (a `curve.csv`): its rows in file order. A missing column, a row with the wrong
/// number of fields, an empty or non-numeric step, minutes or train PSNR, or a non-finite value
/// is an error naming the file and the line. A file with a header and no rows is an empty curve.
pub fn read_curve(path: &Path) -> Result<Vec<CurvePoint>> {
    let bytes = nerf_core::io::limits::read_bounded(path, MAX_CURVE_BYTES)?;
    let text = String::from_utf8(bytes).map_err(|e| Error::invalid(path, format!("not UTF-8 text: {e}")))?;
    parse_curve(&text).map_err(|(line, problem)| Error::invalid(path, format!("line {line}: {problem}")))
}

/// [`read_curve`] on text: the rows, or the 1-based line and what is wrong with it.
fn parse_curve(text: &str) -> std::result::Result<Vec<CurvePoint>, (usize, String)> {
    let mut lines = text.lines().enumerate().map(|(k, l)| (k + 1, l.trim_end_matches('\r')));
    let header = lines.next().map(|(_, h)| h).unwrap_or_default();
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let column = |name: &str| {
        names.iter().position(|n| *n == name).ok_or_else(|| (1, format!("no {name} column (the header is {header:?}; expected {})", COLUMNS.join(","))))
    };
    let [step, minutes, train, val] = [column(COLUMNS[0])?, column(COLUMNS[1])?, column(COLUMNS[2])?, column(COLUMNS[3])?];
    let mut points = Vec::new();
    for (line, row) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err((line, format!("{} fields where the header has {} ({row:?})", fields.len(), names.len())));
        }
        let number = |k: usize| -> std::result::Result<f64, (usize, String)> {
            let (name, field) = (names[k], fields[k]);
            let value: f64 = match field {
                "" => return Err((line, format!("{name} is empty"))),
                f => f.parse().map_err(|_| (line, format!("{name} {f:?} is not a number")))?,
            };
            if !value.is_finite() {
                return Err((line, format!("{name} {field:?} is not finite")));
            }
            Ok(value)
        };
        let step_value = fields[step].parse::<usize>().map_err(|_| (line, format!("step {:?} is not a whole number of steps", fields[step])))?;
        let minutes_value = number(minutes)?;
        if minutes_value < 0.0 {
            return Err((line, format!("minutes {minutes_value} is negative")));
        }
        let val_value = if fields[val].is_empty() { None } else { Some(number(val)? as f32) };
        points.push(CurvePoint { step: step_value, minutes: minutes_value, train_psnr: number(train)? as f32, val_psnr: val_value });
    }
    Ok(points)
}

/// The step reached at `minutes`, read off `points` by linear interpolation between rows (a run
/// starts at step 0 at minute 0); `None` past the last row or for an empty curve.
///
/// Rows (5 min, 2000 steps) and (10 min, 4000 steps): minute 2.5 → 1000, 7.5 → 3000, 11 → `None`.
pub fn step_at(points: &[CurvePoint], minutes: f64) -> Option<f64> {
    let mut known: Vec<(f64, f64)> = points.iter().map(|p| (p.minutes, p.step as f64)).collect();
    known.sort_by(|a, b| a.0.total_cmp(&b.0));
    if known.first().is_some_and(|&(m, _)| m > 0.0) {
        known.insert(0, (0.0, 0.0));
    }
    let last = known.last()?;
    if minutes > last.0 || minutes < 0.0 {
        return None;
    }
    let after = known.iter().position(|&(m, _)| m >= minutes)?;
    let (m1, s1) = known[after];
    let Some(&(m0, s0)) = after.checked_sub(1).map(|k| &known[k]) else { return Some(s1) };
    if m1 <= m0 {
        return Some(s1);
    }
    Some(s0 + (s1 - s0) * (minutes - m0) / (m1 - m0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(step: usize, minutes: f64, train_psnr: f32, val_psnr: Option<f32>) -> CurvePoint {
        CurvePoint { step, minutes, train_psnr, val_psnr }
    }

    #[test]
    fn rows_are_read_with_and_without_val() {
        // The layout `Curve::record` writes, a resumed run's repeated step included, and a row
        // of a run without val views (its val field empty).
        let text = "step,minutes,train_psnr,val_psnr\n2598,5.03,29.260,27.924\n4830,10.03,31.401,29.046\n4830,10.07,31.401,29.046\n5000,11.00,31.5,\n";
        let points = parse_curve(text).unwrap();
        assert_eq!(points.len(), 4);
        assert_eq!(points[0], point(2598, 5.03, 29.26, Some(27.924)));
        assert_eq!(points[3], point(5000, 11.0, 31.5, None));
        // Columns are found by name; CRLF line ends and blank lines are harmless.
        let points = parse_curve("minutes,step,val_psnr,train_psnr\r\n1.5,10,20.5,21\r\n\r\n").unwrap();
        assert_eq!(points, [point(10, 1.5, 21.0, Some(20.5))]);
        // A header alone: no points yet.
        assert!(parse_curve("step,minutes,train_psnr,val_psnr\n").unwrap().is_empty());
    }

    #[test]
    fn bad_rows_name_their_line() {
        let bad = |text: &str| parse_curve(text).unwrap_err();
        let (line, problem) = bad("step,minutes,val_psnr\n1,2,3\n");
        assert_eq!(line, 1);
        assert!(problem.starts_with("no train_psnr column"), "{problem}");
        assert_eq!(bad("").0, 1, "an empty file has no header");
        let (line, problem) = bad("step,minutes,train_psnr,val_psnr\n1,0.5,20,21\n2,1.0,abc,21\n");
        assert_eq!((line, problem.as_str()), (3, "train_psnr \"abc\" is not a number"));
        let (line, problem) = bad("step,minutes,train_psnr,val_psnr\n1,0.5,20\n");
        assert_eq!((line, problem.as_str()), (2, "3 fields where the header has 4 (\"1,0.5,20\")"));
        assert_eq!(bad("step,minutes,train_psnr,val_psnr\n1.5,0.5,20,21\n").1, "step \"1.5\" is not a whole number of steps");
        assert_eq!(bad("step,minutes,train_psnr,val_psnr\n1,,20,21\n").1, "minutes is empty");
        assert_eq!(bad("step,minutes,train_psnr,val_psnr\n1,-2,20,21\n").1, "minutes -2 is negative");
        assert_eq!(bad("step,minutes,train_psnr,val_psnr\n1,2,20,NaN\n").1, "val_psnr \"NaN\" is not finite");
    }

    #[test]
    fn read_curve_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curve.csv");
        std::fs::write(&path, "step,minutes,train_psnr,val_psnr\n1,x,20,21\n").unwrap();
        let err = read_curve(&path).unwrap_err().to_string();
        assert_eq!(err, format!("{}: line 2: minutes \"x\" is not a number", path.display()));
        let err = read_curve(&dir.path().join("missing.csv")).unwrap_err().to_string();
        assert!(err.contains("missing.csv"), "{err}");
    }

    #[test]
    fn steps_are_interpolated_between_rows() {
        let points = [point(2000, 5.0, 20.0, None), point(4000, 10.0, 25.0, None)];
        assert_eq!(step_at(&points, 2.5), Some(1000.0));
        assert_eq!(step_at(&points, 7.5), Some(3000.0));
        assert_eq!(step_at(&points, 10.0), Some(4000.0));
        assert_eq!(step_at(&points, 0.0), Some(0.0));
        assert_eq!(step_at(&points, 11.0), None);
        assert_eq!(step_at(&[], 1.0), None);
        // A resume writes the same step twice a little apart: the later row holds.
        let resumed = [point(10, 1.0, 20.0, None), point(10, 1.1, 20.0, None), point(30, 2.1, 20.0, None)];
        assert_eq!(step_at(&resumed, 1.05), Some(10.0));
        assert_eq!(step_at(&resumed, 1.6), Some(20.0));
    }
}
