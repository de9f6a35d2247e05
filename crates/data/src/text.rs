//! Small helpers shared by the text readers: reading files, numbers with line context, and
//! number formatting that round-trips exactly.

use crate::error::{DataError, ParseErrorKind};
use std::path::Path;

/// Reads a whole text file, naming the file in the error.
pub(crate) fn read_to_string(path: &Path) -> Result<String, DataError> {
    let bytes = std::fs::read(path).map_err(|source| DataError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    bytes_to_string(path, bytes)
}

/// Checks that the bytes are UTF-8, naming the first offending line.
pub(crate) fn bytes_to_string(path: &Path, bytes: Vec<u8>) -> Result<String, DataError> {
    String::from_utf8(bytes).map_err(|e| {
        let valid = e.utf8_error().valid_up_to();
        let line = 1 + e.as_bytes()[..valid]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        DataError::Parse {
            path: path.to_path_buf(),
            line,
            kind: ParseErrorKind::Expected {
                expected: "UTF-8 text".into(),
                found: format!("invalid byte at offset {valid}"),
            },
        }
    })
}

/// A position in a file, for building errors.
#[derive(Clone, Copy)]
pub(crate) struct At<'a> {
    pub path: &'a Path,
    pub line: usize,
}

impl At<'_> {
    /// A parse error at this line.
    pub fn err(&self, kind: ParseErrorKind) -> DataError {
        DataError::Parse {
            path: self.path.to_path_buf(),
            line: self.line,
            kind,
        }
    }

    /// Parses a finite `f64`.
    pub fn number(&self, text: &str, field: &str) -> Result<f64, DataError> {
        let value: f64 = text.parse().map_err(|_| {
            self.err(ParseErrorKind::NotANumber {
                field: field.to_string(),
                text: text.to_string(),
            })
        })?;
        if !value.is_finite() {
            return Err(self.err(ParseErrorKind::NotFinite {
                field: field.to_string(),
                text: text.to_string(),
            }));
        }
        Ok(value)
    }

    /// Parses a non-negative integer.
    pub fn index(&self, text: &str, field: &str) -> Result<u64, DataError> {
        text.parse().map_err(|_| {
            self.err(ParseErrorKind::NotAnIndex {
                field: field.to_string(),
                text: text.to_string(),
            })
        })
    }

    /// Checks the number of fields after the tag.
    pub fn field_count(
        &self,
        record: &str,
        fields: &[&str],
        expected: usize,
    ) -> Result<(), DataError> {
        if fields.len() != expected {
            return Err(self.err(ParseErrorKind::FieldCount {
                record: record.to_string(),
                expected: expected.to_string(),
                found: fields.len(),
            }));
        }
        Ok(())
    }
}

/// Formats `value` so that parsing the text gives back exactly the same `f64`: Rust's shortest
/// round-trip representation, in exponent notation outside `[1e-4, 1e15)`.
pub(crate) fn fmt_f64(value: f64) -> String {
    let magnitude = value.abs();
    if value == 0.0 || (1e-4..1e15).contains(&magnitude) {
        format!("{value}")
    } else {
        format!("{value:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fmt_f64_round_trips() {
        for v in [
            0.0,
            -0.0,
            1.0,
            0.1,
            1.0 / 3.0,
            -2.5e-300,
            1e300,
            123456789.12345679,
            5e-5,
            f64::MIN_POSITIVE,
            f64::MAX,
        ] {
            let text = fmt_f64(v);
            assert_eq!(
                text.parse::<f64>().unwrap().to_bits(),
                v.to_bits(),
                "{text}"
            );
        }
    }
}
