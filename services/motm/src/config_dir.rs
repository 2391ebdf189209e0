//! Finding the `config/` folder.

use std::path::{Path, PathBuf};

/// Picks the config folder: the `--config-dir` flag, then `$MOTM_CONFIG_DIR`, then `./config`,
/// then the `config/` folder of the source tree this binary was built from.
pub fn resolve(flag: Option<PathBuf>) -> PathBuf {
    if let Some(dir) = flag {
        return dir;
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
