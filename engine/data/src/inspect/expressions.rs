//! Expression coefficients beyond the ones the engine conditions on: accepted (the first
//! [`N_EXPRESSION`] are read, the rest checked as finite and left), and said, so that
//! nothing is ignored silently.

use std::path::Path;

use serde_json::Value;
use talkin_human::body::N_EXPRESSION;

use crate::dataset::INDEX_FILE;
use crate::params_json::expression_count;

/// A note when frames of the dataset in `root` carry more than [`N_EXPRESSION`]
/// expression coefficients; `None` when none do (or the index cannot be read, which
/// loading the dataset reports on its own).
pub fn extra_expression_note(root: &Path) -> Option<String> {
    let text = std::fs::read_to_string(root.join(INDEX_FILE)).ok()?;
    let doc: Value = serde_json::from_str(text.trim_start_matches('\u{feff}')).ok()?;
    let frames = doc.get("frames")?.as_array()?;
    let extra: Vec<usize> = frames
        .iter()
        .filter_map(|f| f.get("params").and_then(expression_count))
        .filter(|&n| n > N_EXPRESSION)
        .collect();
    let most = extra.iter().max()?;
    Some(format!(
        "{} of {} frames carry more than {N_EXPRESSION} expression coefficients (up to \
         {most}): the engine conditions on the first {N_EXPRESSION} and ignores the rest",
        extra.len(),
        frames.len()
    ))
}
