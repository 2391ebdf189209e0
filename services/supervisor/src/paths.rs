//! Finding the config folder and scenario files, as the `motm` CLI does.

use std::path::{Path, PathBuf};

/// The config folder: `flag` (a `--config-dir`), then `$MOTM_CONFIG_DIR`, then `./config`,
/// then the `config/` folder of the source tree this binary was built from.
pub fn config_dir(flag: Option<PathBuf>) -> PathBuf {
    flag.or_else(|| std::env::var_os("MOTM_CONFIG_DIR").map(PathBuf::from))
        .unwrap_or_else(|| {
            let local = Path::new("config");
            if local.join("robots").is_dir() {
                local.to_path_buf()
            } else {
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
            }
        })
}

/// A scenario file: `name` itself when it is an existing file, else
/// `<config_dir>/scenarios/<name>.toml`.
pub fn scenario_path(config_dir: &Path, name: &str) -> PathBuf {
    let direct = PathBuf::from(name);
    if direct.is_file() {
        direct
    } else {
        config_dir.join("scenarios").join(format!("{name}.toml"))
    }
}
