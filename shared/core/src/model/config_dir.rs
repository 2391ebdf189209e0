//! Finding the `config/` folder that holds `robots/`, `scenarios/` and the stack configs. Every
//! binary of the project resolves it the same way.

use std::path::{Path, PathBuf};

/// The config folder: `flag` (a `--config-dir`), then `$MOTM_CONFIG_DIR`, then `./config` when it
/// holds `robots/`, then the `config/` folder of the source tree the binary was built from.
pub fn resolve_config_dir(flag: Option<&Path>) -> PathBuf {
    if let Some(dir) = flag {
        return dir.to_path_buf();
    }
    if let Some(dir) = std::env::var_os("MOTM_CONFIG_DIR") {
        return PathBuf::from(dir);
    }
    let local = Path::new("config");
    if local.join("robots").is_dir() {
        return local.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}
