//! Checking the command line before any work starts, naming library enums on the command line,
//! and reporting errors once.
//!
//! Every command validates its arguments first — inputs exist, outputs can be written, values
//! are in range — so that a mistake costs no computation and leaves nothing half-written. The
//! rule for outputs: every command writes to a folder or file it is given (`--out`), and a
//! default never points into the repository's committed results (defaults live under `out/`).

use anyhow::{Context, Result, bail};
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use std::path::Path;

/// A library enum that the command line names: its values with their names and a line of
/// help each. Implemented here for the library's own enums (the libraries know no command
/// line), by listing their `ALL` and calling their `name()`, so the variants are not copied.
pub trait Named: Sized + Copy + Send + Sync + 'static {
    /// Every value, in the order the help lists them.
    fn all() -> &'static [Self];
    /// The command-line name.
    fn name(self) -> &'static str;
    /// One line of help.
    fn help(self) -> &'static str;
}

/// A clap value parser for a [`Named`] enum: possible values and their help from the library.
pub fn parser<T: Named + Clone>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(
        T::all()
            .iter()
            .map(|v| PossibleValue::new(v.name()).help(v.help())),
    )
    .map(|s| {
        *T::all()
            .iter()
            .find(|v| v.name() == s)
            .expect("clap accepts only the listed names")
    })
}

/// An input file that must exist and be a readable file; `what` names the argument.
pub fn input_file(path: &Path, what: &str) -> Result<()> {
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{what} {}: no such file", path.display())
        }
        Err(e) => bail!("{what} {}: {e}", path.display()),
        Ok(m) if m.is_dir() => bail!("{what} {}: is a folder, expected a file", path.display()),
        Ok(_) => std::fs::File::open(path)
            .map(|_| ())
            .with_context(|| format!("{what} {}: cannot be read", path.display())),
    }
}

/// An input folder that must exist.
pub fn input_dir(path: &Path, what: &str) -> Result<()> {
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{what} {}: no such folder", path.display())
        }
        Err(e) => bail!("{what} {}: {e}", path.display()),
        Ok(m) if !m.is_dir() => bail!("{what} {}: is a file, expected a folder", path.display()),
        Ok(_) => Ok(()),
    }
}

/// An output folder: created if missing, and checked to be writable by creating and removing
/// a probe file in it.
/// The system's parameters from `--config FILE` (and the file's text, kept in a saved map), or
/// the defaults.
pub fn system_config(path: Option<&Path>) -> Result<(system::SystemConfig, String)> {
    match path {
        Some(path) => {
            input_file(path, "--config")?;
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("--config {}", path.display()))?;
            Ok((system::SystemConfig::from_file(path)?, text))
        }
        None => Ok((system::SystemConfig::default(), String::new())),
    }
}

pub fn output_dir(path: &Path, what: &str) -> Result<()> {
    if path.is_file() {
        bail!("{what} {}: is a file, expected a folder", path.display());
    }
    std::fs::create_dir_all(path).map_err(|e| {
        anyhow::anyhow!("{what} {}: cannot create the folder ({e})", path.display())
    })?;
    probe(path).map_err(|e| anyhow::anyhow!("{what} {}: cannot write there ({e})", path.display()))
}

/// An output file: its folder is created if missing and must be writable; the file itself is
/// not created (a failed run leaves nothing behind).
pub fn output_file(path: &Path, what: &str) -> Result<()> {
    if path.is_dir() {
        bail!("{what} {}: is a folder, expected a file", path.display());
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(parent).map_err(|e| {
        anyhow::anyhow!("{what} {}: cannot create its folder ({e})", path.display())
    })?;
    probe(parent)
        .map_err(|e| anyhow::anyhow!("{what} {}: cannot write there ({e})", path.display()))
}

fn probe(dir: &Path) -> std::io::Result<()> {
    let probe = dir.join(format!(".dwslam-write-probe-{}", std::process::id()));
    std::fs::write(&probe, b"")?;
    std::fs::remove_file(&probe)
}

/// A number that must be finite and positive.
pub fn positive(value: f64, what: &str) -> Result<()> {
    if !(value.is_finite() && value > 0.0) {
        bail!("{what} must be a positive number (got {value})");
    }
    Ok(())
}

/// An error and its causes on one line, each cause once: a cause whose text the message before
/// it already contains is left out (a library error that names the file and an `io::Error`
/// that says "No such file" are not printed twice).
pub fn describe(error: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if parts.last().is_some_and(|last| last.contains(&text)) {
            continue;
        }
        parts.push(text);
    }
    parts.join(": ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn causes_are_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let e = anyhow::Error::new(io)
            .context("cannot decode image a.png: No such file")
            .context("the first frame");
        assert_eq!(
            describe(&e),
            "the first frame: cannot decode image a.png: No such file"
        );
    }

    #[test]
    fn inputs_and_outputs_are_checked() {
        let dir = std::env::temp_dir().join(format!("dwslam-args-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("a.txt");
        std::fs::write(&file, "x").unwrap();
        assert!(input_file(&file, "FILE").is_ok());
        let missing = input_file(&dir.join("b.txt"), "FILE")
            .unwrap_err()
            .to_string();
        assert!(missing.ends_with("no such file"), "{missing}");
        assert!(input_file(&dir, "FILE").is_err());
        assert!(input_dir(&file, "DIR").is_err());
        assert!(output_dir(&file, "--out").is_err());
        assert!(output_dir(&dir.join("new/sub"), "--out").is_ok());
        assert!(output_file(&dir.join("x/y.json"), "--json").is_ok());
        assert!(!dir.join("x/y.json").exists(), "the file is not created");
        assert!(output_file(&dir, "--json").is_err());
        assert!(positive(0.0, "--noise").is_err() && positive(f64::NAN, "--noise").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
