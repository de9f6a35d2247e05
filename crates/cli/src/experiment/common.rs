//! What the experiments share: the `summary.json` an earlier run left, into which each part of
//! an experiment merges its keys ([`read_summary`]), and progress bars ([`progress`], also used
//! by `dwslam render` and `dwslam vocabulary`). A leaf: it imports none of the experiments.

use anyhow::{Context, Result};

/// The `summary.json` an earlier run left at `path` (empty if there is none): parts of an
/// experiment may be run separately, each merging its keys into the summary.
pub(crate) fn read_summary(
    path: &std::path::Path,
) -> Result<serde_json::Map<String, serde_json::Value>> {
    match std::fs::read_to_string(path) {
        Ok(text) => serde_json::from_str(&text)
            .with_context(|| format!("{}: not a JSON object", path.display())),
        Err(_) => Ok(serde_json::Map::new()),
    }
}

/// A progress bar of `len` steps labelled `what`.
pub(crate) fn progress(len: usize, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:<28} [{elapsed_precise}] {wide_bar} {pos}/{len} (eta {eta})",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}
