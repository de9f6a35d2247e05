//! Where the real datasets are: the one place tests, benchmarks and tools look them up.
//!
//! The datasets live outside the repository (they are never copied into it): in the directory
//! named by the environment variable [`DATA_ENV`] (`DWSLAM_DATA`), else in `../shared/data`
//! beside the workspace root. A test that needs a dataset calls [`require`]; when the data is
//! absent it prints `skipping <test>: <path> not found` and the test returns early, unless
//! [`REQUIRE_ENV`] (`DWSLAM_REQUIRE_DATA=1`, set by `.ci/run`) is set, in which case it panics so
//! that CI can never skip silently.

use std::path::{Path, PathBuf};

/// Environment variable naming the dataset directory.
pub const DATA_ENV: &str = "DWSLAM_DATA";

/// Environment variable that, set to `1`, turns a missing dataset in [`require`] into a panic.
pub const REQUIRE_ENV: &str = "DWSLAM_REQUIRE_DATA";

/// The workspace root: two levels above this crate's manifest directory.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("..")
        .components()
        .collect()
}

/// The dataset directory: `$DWSLAM_DATA` if that variable is set and non-empty, else
/// `<workspace root>/../shared/data`; `None` if the chosen directory does not exist.
pub fn dataset_root() -> Option<PathBuf> {
    let candidate = match std::env::var_os(DATA_ENV) {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => workspace_root().join("..").join("shared").join("data"),
    };
    candidate.is_dir().then_some(candidate)
}

/// `relative` inside the dataset directory, if the directory and the file (or folder) exist.
pub fn dataset_path(relative: impl AsRef<Path>) -> Option<PathBuf> {
    let path = dataset_root()?.join(relative);
    path.exists().then_some(path)
}

/// `true` when [`REQUIRE_ENV`] is set to `1`.
pub fn data_required() -> bool {
    std::env::var(REQUIRE_ENV).is_ok_and(|v| v.trim() == "1")
}

/// For tests: the dataset file `relative`, or `None` after printing
/// `skipping <test>: <path> not found` (the test name is the current thread's, which the test
/// harness sets). Panics instead of returning `None` when `DWSLAM_REQUIRE_DATA=1`.
pub fn require(relative: impl AsRef<Path>) -> Option<PathBuf> {
    let relative = relative.as_ref();
    if let Some(path) = dataset_path(relative) {
        return Some(path);
    }
    let shown = match dataset_root() {
        Some(root) => root.join(relative),
        None => PathBuf::from(format!(
            "${DATA_ENV} or ../shared/data (missing)/{}",
            relative.display()
        )),
    };
    let thread = std::thread::current();
    let test = thread.name().unwrap_or("test");
    if data_required() {
        panic!(
            "{test}: {} not found and {REQUIRE_ENV}=1 forbids skipping",
            shown.display()
        );
    }
    eprintln!("skipping {test}: {} not found", shown.display());
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workspace_root_holds_the_workspace_manifest() {
        let manifest = std::fs::read_to_string(workspace_root().join("Cargo.toml")).unwrap();
        assert!(manifest.contains("[workspace]"));
    }

    #[test]
    fn missing_file_is_none_or_panics_when_required() {
        let name = "no/such/dataset/file.txt";
        let result = std::panic::catch_unwind(|| require(name));
        if data_required() {
            assert!(result.is_err());
        } else {
            assert_eq!(result.unwrap(), None);
        }
    }
}
