//! `config/iceoryx2.toml` is a valid iceoryx2 0.10 config whose values are iceoryx2's own
//! defaults (so processes that find it and processes that do not agree on every service), and
//! a bad config file is a clear error naming the file.

use std::path::Path;

use iceoryx2::config::Config;
use iceoryx2::prelude::SemanticString;
use motm_bus::{BusError, IpcConfig};

fn shipped() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/iceoryx2.toml")
}

#[test]
fn the_shipped_config_loads_and_keeps_iceoryx2_defaults() {
    let ipc = IpcConfig {
        prefix: "motmt_cfg_".into(),
    };
    let config = ipc.iceoryx2_from(Some(&shipped())).unwrap();
    assert_eq!(config.global.prefix.as_bytes(), b"motmt_cfg_");
    let mut expected = Config::default();
    expected.global.prefix = config.global.prefix;
    assert_eq!(config, expected);
}

#[test]
fn a_bad_config_file_names_the_file() {
    let ipc = IpcConfig::default();
    let dir = std::env::temp_dir().join(format!("motm-iox-cfg-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("iceoryx2.toml");
    std::fs::write(&bad, "[global]\nroot-path = 3\n").unwrap();
    for path in [bad.clone(), dir.join("missing.toml")] {
        let err = ipc.iceoryx2_from(Some(&path)).unwrap_err();
        assert!(matches!(err, BusError::Config { .. }), "{err}");
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
