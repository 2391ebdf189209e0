//! Errors raised while loading robot models and configuration files.

use std::path::{Path, PathBuf};

/// A model, URDF or configuration file that cannot be used, with the file and the element at fault.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The file is readable but one of its elements or keys is wrong.
    #[error("{}: {element}: {message}", file.display())]
    Invalid {
        /// The file at fault.
        file: PathBuf,
        /// The element, attribute or key at fault (e.g. `joint 'panda_joint3' <limit upper>`).
        element: String,
        /// What is wrong with it.
        message: String,
    },
    /// The file cannot be read at all.
    #[error("{}: cannot read: {source}", file.display())]
    Io {
        /// The file that could not be read.
        file: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A robot name that has no configuration.
    #[error("{}: unknown robot '{name}': expected one of {}", file.display(), known.join(", "))]
    UnknownRobot {
        /// The configuration file the name would need (`<config_dir>/robots/<name>.toml`).
        file: PathBuf,
        /// The name that was asked for.
        name: String,
        /// The names that exist.
        known: Vec<String>,
    },
}

impl ModelError {
    /// Builds an [`ModelError::Invalid`] for `file`.
    pub fn invalid(file: &Path, element: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            file: file.to_path_buf(),
            element: element.into(),
            message: message.into(),
        }
    }

    /// Checks that every `(key, value)` of `file` is finite and positive; the error names the
    /// first key that is not.
    pub fn check_positive(file: &Path, values: &[(&str, f64)]) -> Result<(), Self> {
        match values
            .iter()
            .find(|(_, value)| !(value.is_finite() && *value > 0.0))
        {
            Some(&(key, value)) => Err(Self::invalid(
                file,
                key,
                format!("must be finite and positive, got {value}"),
            )),
            None => Ok(()),
        }
    }

    /// Reads `file` to a string, naming the file on failure.
    pub fn read_to_string(file: &Path) -> Result<String, Self> {
        std::fs::read_to_string(file).map_err(|source| Self::Io {
            file: file.to_path_buf(),
            source,
        })
    }

    /// Parses a strict TOML file (unknown keys rejected by the target type), naming the file and key on failure.
    pub fn parse_toml<T: serde::de::DeserializeOwned>(file: &Path) -> Result<T, Self> {
        let text = Self::read_to_string(file)?;
        Self::parse_toml_str(file, &text)
    }

    /// Parses TOML text that came from `file`, naming the file and key on failure.
    pub fn parse_toml_str<T: serde::de::DeserializeOwned>(
        file: &Path,
        text: &str,
    ) -> Result<T, Self> {
        toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| {
                    let number = text[..s.start].matches('\n').count() + 1;
                    let content = text.lines().nth(number - 1).unwrap_or("").trim();
                    format!("line {number} `{content}`")
                })
                .unwrap_or_else(|| "document".to_string());
            Self::invalid(file, line, e.message().trim().to_string())
        })
    }
}
