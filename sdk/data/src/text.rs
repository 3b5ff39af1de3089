//! Small helpers for line-oriented numeric text files: every number is checked to be finite
//! and every error names the file and the 1-based line.

use crate::error::DataError;
use std::path::Path;

/// Reads a whole dataset text file (a regular file of at most
/// [`MAX_DATASET_FILE_BYTES`](crate::input_limits::MAX_DATASET_FILE_BYTES)).
pub(crate) fn read(path: &Path) -> Result<String, DataError> {
    human2nav_core::input::read_user_file(
        path,
        "dataset file",
        crate::input_limits::MAX_DATASET_FILE_BYTES,
    )
    .map_err(|e| DataError::io(path, e))
}

/// Parses one finite `f64` token; `field` names the column in the error.
pub(crate) fn number(tok: &str, path: &Path, line: usize, field: &str) -> Result<f64, DataError> {
    let v: f64 = tok
        .trim()
        .parse()
        .map_err(|_| DataError::parse(path, line, format!("{field}: `{tok}` is not a number")))?;
    if !v.is_finite() {
        return Err(DataError::NonFinite {
            path: path.to_path_buf(),
            line,
            field: field.to_string(),
            value: tok.to_string(),
        });
    }
    Ok(v)
}

/// Parses a non-negative integer that may be written as a float (`7.8000000e+02`).
pub(crate) fn integer(tok: &str, path: &Path, line: usize, field: &str) -> Result<i64, DataError> {
    let v = number(tok, path, line, field)?;
    if v.fract() != 0.0 || v.abs() > 9.0e15 {
        return Err(DataError::parse(
            path,
            line,
            format!("{field}: `{tok}` is not an integer"),
        ));
    }
    Ok(v as i64)
}

/// Splits a line into whitespace-separated tokens and checks there are at least `n`.
pub(crate) fn fields<'a>(
    text: &'a str,
    n: usize,
    path: &Path,
    line: usize,
) -> Result<Vec<&'a str>, DataError> {
    let toks: Vec<&str> = text.split_whitespace().collect();
    if toks.len() < n {
        return Err(DataError::parse(
            path,
            line,
            format!("expected at least {n} columns, found {}", toks.len()),
        ));
    }
    Ok(toks)
}

/// One row `frame id x y` of a four-column file (the sgan/Trajectron and TrajNet formats),
/// `id_field` naming the id column in errors. Blank lines give `None`.
pub(crate) fn frame_id_xy(
    line: &str,
    path: &Path,
    ln: usize,
    id_field: &str,
) -> Result<Option<(i64, u64, f64, f64)>, DataError> {
    if line.trim().is_empty() {
        return Ok(None);
    }
    let toks = fields(line, 4, path, ln)?;
    if toks.len() != 4 {
        return Err(DataError::parse(
            path,
            ln,
            format!("expected `frame id x y`, found {} columns", toks.len()),
        ));
    }
    let frame = integer(toks[0], path, ln, "frame")?;
    let id = integer(toks[1], path, ln, id_field)?;
    let x = number(toks[2], path, ln, "x")?;
    let y = number(toks[3], path, ln, "y")?;
    let id = u64::try_from(id)
        .map_err(|_| DataError::parse(path, ln, format!("negative {id_field}")))?;
    Ok(Some((frame, id, x, y)))
}
