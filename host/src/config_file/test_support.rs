//! What the configuration tests share: a base configuration and parsers
//! whose errors name a file that does not exist.

use std::path::{Path, PathBuf};

use super::errors::Result;
use super::{ConfigFileError, ProcessingConfig};

pub(super) fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

pub(super) const BASE: &str = r#"
[camera]
width = 64
height = 48
bit_depth = 12

[subapertures.grid]
x = 0
y = 0
columns = 4
rows = 3
width = 16
height = 16
"#;

/// Parses `text` as if it were `dir/c.toml`.
pub(super) fn parse_in(dir: &Path, text: &str) -> Result<ProcessingConfig> {
    ProcessingConfig::from_toml_str(text, &dir.join("c.toml"))
}

pub(super) fn parse(text: &str) -> Result<ProcessingConfig> {
    parse_in(Path::new("/nonexistent/conf"), text)
}

pub(super) fn invalid(text: &str) -> ConfigFileError {
    let err = parse(text).unwrap_err();
    assert!(
        err.to_string().starts_with("/nonexistent/conf/c.toml: "),
        "{err}"
    );
    err
}
