//! SuPerMVO configuration.
//!
//! One serde struct per concern, `deny_unknown_fields` everywhere so a misspelt key is an
//! error rather than a silently ignored default, defaults for every option, and
//! [`Config::validate`] naming the offending key and its allowed range.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use supermvo_eval::{DeltaUnit, EvalOptions};

/// A configuration problem: file, key and what is allowed.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// Config file.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax error, unknown key or wrong type (the message names key and line).
    #[error("{path}: {message}")]
    Parse {
        /// Config file.
        path: PathBuf,
        /// Parser message.
        message: String,
    },
    /// A value outside its allowed range.
    #[error("config key '{key}' = {value}: {allowed}")]
    OutOfRange {
        /// Dotted key.
        key: String,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: String,
    },
}

/// Top-level configuration (`config/default.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Trajectory evaluation defaults.
    pub eval: EvalConfig,
}

/// `[eval]`: defaults of `supermvo eval`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Alignment: "none", "se3", "sim3" or "scale".
    pub align: supermvo_geometry::AlignmentKind,
    /// RPE step (positive; an integer when `delta_unit = "frames"`).
    pub delta: f64,
    /// RPE step unit: "frames" or "meters".
    pub delta_unit: DeltaUnit,
    /// Association tolerance in seconds, (0, 10].
    pub t_max_diff: f64,
    /// Choose RPE pairs along the reference instead of the estimate.
    pub pairs_from_reference: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        let o = EvalOptions::default();
        Self {
            align: o.align,
            delta: o.delta,
            delta_unit: o.delta_unit,
            t_max_diff: o.t_max_diff,
            pairs_from_reference: o.pairs_from_reference,
        }
    }
}

impl EvalConfig {
    /// The evaluation options these settings describe.
    pub fn options(&self) -> EvalOptions {
        EvalOptions {
            align: self.align,
            delta: self.delta,
            delta_unit: self.delta_unit,
            t_max_diff: self.t_max_diff,
            pairs_from_reference: self.pairs_from_reference,
        }
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |key: &str, value: String, allowed: &str| {
            Err(ConfigError::OutOfRange {
                key: key.into(),
                value,
                allowed: allowed.into(),
            })
        };
        if !(self.delta.is_finite() && self.delta > 0.0) {
            return bad("eval.delta", self.delta.to_string(), "must be positive");
        }
        if self.delta_unit == DeltaUnit::Frames && self.delta.fract() != 0.0 {
            return bad(
                "eval.delta",
                self.delta.to_string(),
                "must be a whole number of frames when eval.delta_unit = \"frames\"",
            );
        }
        if !(self.t_max_diff > 0.0 && self.t_max_diff <= 10.0) {
            return bad(
                "eval.t_max_diff",
                self.t_max_diff.to_string(),
                "must be in (0, 10] seconds",
            );
        }
        Ok(())
    }
}

impl Config {
    /// Parses TOML text; `origin` names the source in errors.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let cfg: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: origin.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads and validates a TOML file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Self::from_toml(&text, path)
    }

    /// Validates every section.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.eval.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_key_is_named() {
        let err = Config::from_toml("[eval]\nallign = \"sim3\"\n", Path::new("my.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("my.toml") && err.contains("allign") && err.contains("line 2"),
            "{err}"
        );
    }

    #[test]
    fn out_of_range_names_key() {
        let err = Config::from_toml("[eval]\nt_max_diff = -1.0\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("eval.t_max_diff"), "{err}");
        let err = Config::from_toml("[eval]\ndelta = 2.5\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("whole number"), "{err}");
    }

    #[test]
    fn shipped_default_config_parses_and_equals_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/default.toml");
        let cfg = Config::load(&path).unwrap();
        assert_eq!(cfg, Config::default());
    }
}
