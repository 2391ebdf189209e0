//! Where the service binaries are: next to the running executable (all workspace binaries
//! land in one target folder), and building them with Cargo when they are missing.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The folder of the running executable, where the service binaries are looked for.
pub fn own_dir() -> std::io::Result<PathBuf> {
    let exe = std::env::current_exe()?;
    Ok(exe
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf))
}

/// The path of binary `name` in `dir`.
pub fn binary_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX))
}

/// The names in `names` that have no executable file in `dir`.
pub fn missing<'a>(dir: &Path, names: impl IntoIterator<Item = &'a str>) -> Vec<String> {
    names
        .into_iter()
        .filter(|name| !binary_path(dir, name).is_file())
        .map(str::to_owned)
        .collect()
}

/// Whether `dir` is a Cargo release folder (`.../release`), to build with the same profile.
pub fn is_release_dir(dir: &Path) -> bool {
    dir.file_name().is_some_and(|n| n == "release")
}

/// Builds `packages` with `cargo` (the `$CARGO` of a `cargo run`) in the profile of `dir`.
/// Cargo's own output goes to stderr. Returns an error message when the build fails.
pub fn cargo_build(cargo: &Path, dir: &Path, packages: &[String]) -> Result<(), String> {
    let mut command = Command::new(cargo);
    command.arg("build").arg("--quiet");
    if is_release_dir(dir) {
        command.arg("--release");
    }
    for package in packages {
        command.arg("-p").arg(package);
    }
    let status = command
        .status()
        .map_err(|e| format!("cannot run {}: {e}", cargo.display()))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!(
            "`cargo build -p {}` failed ({status})",
            packages.join(" -p ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_lists_only_absent_binaries() {
        let dir = own_dir().unwrap();
        let own = std::env::current_exe().unwrap();
        let own_name = own.file_name().unwrap().to_str().unwrap();
        let found = missing(&dir, [own_name, "no-such-motm-service"]);
        assert_eq!(found, ["no-such-motm-service"]);
        assert!(is_release_dir(Path::new("/t/release")));
        assert!(!is_release_dir(Path::new("/t/debug/deps")));
    }
}
