use std::path::PathBuf;

/// Everything that can go wrong reading or writing datasets and trajectories.
///
/// Each variant names the file and, where there is one, the 1-based line.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A line does not have the expected content.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// File concerned.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong and what was expected.
        message: String,
    },
    /// The file holds no data lines.
    #[error("{path}: file is empty (no data lines); expected {expected}")]
    Empty {
        /// File concerned.
        path: PathBuf,
        /// What a data line should look like.
        expected: String,
    },
    /// The dataset as a whole is inconsistent (missing files, mismatched counts...).
    #[error("{path}: {message}")]
    Invalid {
        /// File or directory concerned.
        path: PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
}

impl DatasetError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        if source.kind() == std::io::ErrorKind::InvalidData {
            // a line reader met bytes that are not UTF-8: a binary file where text belongs
            return Self::Invalid {
                path: path.into(),
                message: "not a text file (it holds bytes that are not UTF-8 text); give the text file this expects".into(),
            };
        }
        Self::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }
    pub(crate) fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Parses whitespace- or comma-separated numbers, rejecting non-numeric and non-finite ones.
pub(crate) fn parse_numbers(
    fields: &[&str],
    path: &std::path::Path,
    line: usize,
) -> Result<Vec<f64>, DatasetError> {
    fields
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let v: f64 = f.trim().parse().map_err(|_| {
                DatasetError::parse(
                    path,
                    line,
                    format!("column {}: '{}' is not a number", i + 1, f.trim()),
                )
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(DatasetError::parse(
                    path,
                    line,
                    format!("column {}: value '{}' is not finite", i + 1, f.trim()),
                ))
            }
        })
        .collect()
}
