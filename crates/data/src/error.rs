//! Errors of the dataset readers: every one names the file, and the line where there is one.

use std::path::PathBuf;
use thiserror::Error;

/// Why a dataset file could not be read.
#[derive(Debug, Error)]
pub enum DataError {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A line of the file is malformed.
    #[error("{}:{line}: {kind}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
        /// What was wrong and what was expected.
        kind: ParseErrorKind,
    },
    /// The file as a whole is malformed (empty, counts that disagree with its header, …).
    #[error("{}: {kind}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What was wrong and what was expected.
        kind: ParseErrorKind,
    },
}

impl DataError {
    /// The 1-based line number of a [`DataError::Parse`] error.
    pub fn line(&self) -> Option<usize> {
        match self {
            DataError::Parse { line, .. } => Some(*line),
            _ => None,
        }
    }

    /// The kind of a parse or file error.
    pub fn kind(&self) -> Option<&ParseErrorKind> {
        match self {
            DataError::Parse { kind, .. } | DataError::File { kind, .. } => Some(kind),
            DataError::Io { .. } => None,
        }
    }
}

/// What is wrong with a line or a file.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ParseErrorKind {
    /// A record has the wrong number of fields.
    #[error("{record}: expected {expected} fields after the tag, found {found}")]
    FieldCount {
        /// The record's tag or name.
        record: String,
        /// How many fields were expected (a number or a description).
        expected: String,
        /// How many were found.
        found: usize,
    },
    /// A field is not a number.
    #[error("{field}: expected a number, found {text:?}")]
    NotANumber {
        /// Which field.
        field: String,
        /// The offending text.
        text: String,
    },
    /// A field is not a non-negative integer.
    #[error("{field}: expected a non-negative integer, found {text:?}")]
    NotAnIndex {
        /// Which field.
        field: String,
        /// The offending text.
        text: String,
    },
    /// A number is NaN or infinite.
    #[error("{field}: expected a finite number, found {text:?}")]
    NotFinite {
        /// Which field.
        field: String,
        /// The offending text.
        text: String,
    },
    /// A quaternion or rotation does not describe a rotation.
    #[error("{what}: {source}")]
    InvalidRotation {
        /// Which rotation.
        what: String,
        /// Why.
        source: lie::LieError,
    },
    /// An information matrix is not positive definite (its Cholesky factorisation failed).
    #[error("information matrix is not positive definite: {matrix}")]
    InformationNotPositiveDefinite {
        /// The matrix, row by row.
        matrix: String,
    },
    /// An information matrix is not symmetric.
    #[error("information matrix is not symmetric (max |Λ − Λᵀ| = {asymmetry:e})")]
    InformationNotSymmetric {
        /// The largest entry of `|Λ − Λᵀ|`.
        asymmetry: f64,
    },
    /// A vertex id appears twice.
    #[error("vertex {id} is defined twice (first on line {first_line})")]
    DuplicateVertex {
        /// The id.
        id: u64,
        /// Where it was first defined (0 when not read from a file).
        first_line: usize,
    },
    /// An edge or FIX refers to a vertex that is not defined.
    #[error("vertex {id} is not defined by any VERTEX line")]
    UnknownVertex {
        /// The id.
        id: u64,
    },
    /// An edge connects a vertex to itself.
    #[error("edge connects vertex {id} to itself")]
    SelfLoop {
        /// The id.
        id: u64,
    },
    /// 2D and 3D records in one file.
    #[error("{tag} is {found}D but line {first_line} ({first_tag}) made this a {expected}D file")]
    MixedDimensions {
        /// The offending tag.
        tag: String,
        /// Its dimension.
        found: usize,
        /// The file's dimension.
        expected: usize,
        /// The tag that fixed the dimension.
        first_tag: String,
        /// Where it was.
        first_line: usize,
    },
    /// The file holds no records.
    #[error("file is empty: expected {expected}")]
    Empty {
        /// What was expected.
        expected: String,
    },
    /// A count disagrees with the file's header or with another count.
    #[error("{what}: the header says {expected}, the file has {found}")]
    CountMismatch {
        /// What is counted.
        what: String,
        /// The header's count.
        expected: usize,
        /// The actual count.
        found: usize,
    },
    /// An index is out of range.
    #[error("{what} index {index} is out of range (there are {count})")]
    IndexOutOfRange {
        /// What kind of index.
        what: String,
        /// The index.
        index: u64,
        /// How many there are.
        count: usize,
    },
    /// A YAML document that does not parse or does not have the expected keys and types.
    #[error("YAML: {message}")]
    Yaml {
        /// The YAML parser's message (with the column where it has one).
        message: String,
    },
    /// Anything else: what was expected and what was found.
    #[error("expected {expected}, found {found}")]
    Expected {
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
}
