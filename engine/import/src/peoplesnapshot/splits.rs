//! Which frames the rows of InstantAvatar's split files belong to: the subjects' ranges
//! it names, and its per-subject yaml (`confs/dataset/peoplesnapshot/<subject>.yaml`).

use std::path::Path;

use super::ImportError;
use talkin_data::dataset::Split;

/// A split's frames: `sorted(images)[start..=end]` every `skip`th.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Range {
    pub start: usize,
    pub end: usize,
    pub skip: usize,
}

impl Range {
    pub fn indices(self) -> impl Iterator<Item = usize> {
        (self.start..=self.end).step_by(self.skip.max(1))
    }

    /// The indices that exist among `n` images, as Python's `sorted(images)[start:end +
    /// 1:skip]` keeps them.
    pub(super) fn frames(self, n: usize) -> Vec<usize> {
        self.indices().take_while(|&i| i < n).collect()
    }
}

/// The split names of InstantAvatar's files and yaml, in the order the importer keeps a
/// frame that is in two of them, with the split each becomes.
pub(super) const SPLITS: [(&str, Split); 3] = [
    ("train", Split::Train),
    ("val", Split::TestSame),
    ("test", Split::TestSame),
];

/// InstantAvatar's train, val and test ranges of the PeopleSnapshot subjects.
pub fn known_ranges(subject: &str) -> Option<[Range; 3]> {
    let r = |start, end, skip| Range { start, end, skip };
    Some(match subject {
        "male-3-casual" => [r(0, 455, 4), r(456, 456, 4), r(456, 675, 4)],
        "male-4-casual" => [r(0, 659, 6), r(660, 660, 6), r(660, 872, 6)],
        "female-3-casual" => [r(0, 445, 4), r(446, 446, 4), r(446, 647, 4)],
        "female-4-casual" => [r(0, 335, 4), r(335, 335, 4), r(335, 523, 4)],
        "male-2-casual" | "male-2-sport" => [r(1, 455, 4), r(455, 455, 8), r(1, 455, 20)],
        "male-3-sport" => [r(1, 230, 2), r(230, 230, 6), r(230, 460, 6)],
        "female-4-sport" => [r(1, 336, 4), r(336, 336, 8), r(336, 524, 4)],
        _ => return None,
    })
}

/// The subjects [`known_ranges`] names.
pub(super) const KNOWN_SUBJECTS: [&str; 8] = [
    "male-3-casual",
    "male-4-casual",
    "female-3-casual",
    "female-4-casual",
    "male-2-casual",
    "male-2-sport",
    "male-3-sport",
    "female-4-sport",
];

/// The train, val and test ranges of an InstantAvatar dataset yaml
/// (`confs/dataset/peoplesnapshot/<subject>.yaml`): the blocks `train:`, `val:` and `test:`
/// (under `opt:` there) with `start`, `end` (inclusive) and `skip` (default 1, as
/// InstantAvatar's `opt.get("skip", 1)`). Only block mappings of plain integers are read;
/// other keys, such as `num_workers` or `${...}` references, are ignored.
pub fn parse_splits_yaml(text: &str, file: &Path) -> Result<[Range; 3], ImportError> {
    let blocks = range_blocks(text, file)?;
    let range = |split: &str| split_range(&blocks, split, file);
    Ok([range("train")?, range("val")?, range("test")?])
}

/// A block's `start`, `end` and `skip`, each where given.
type Fields = [Option<usize>; 3];

/// Every block under a split's key that gives a frame field, by its dotted path
/// (`dataset.opt.train`), in the order met.
fn range_blocks(text: &str, file: &Path) -> Result<Vec<(String, Fields)>, ImportError> {
    let mut blocks: Vec<(String, Fields)> = Vec::new();
    // The open mapping keys: (indent, key).
    let mut open: Vec<(usize, String)> = Vec::new();
    for raw in text.lines() {
        let line = strip_comment(raw);
        if line.trim().is_empty() {
            continue;
        }
        let indent = line.len() - line.trim_start().len();
        while open.last().is_some_and(|(i, _)| *i >= indent) {
            open.pop();
        }
        let Some((key, value)) = line.trim().split_once(':') else {
            continue;
        };
        let (key, value) = (key.trim(), value.trim());
        if value.is_empty() {
            open.push((indent, key.to_string()));
            continue;
        }
        let field = ["start", "end", "skip"].iter().position(|f| *f == key);
        let parent = open.last().map(|(_, k)| k.as_str());
        let (Some(field), Some(parent)) = (field, parent) else {
            continue;
        };
        if !SPLITS.iter().any(|(s, _)| *s == parent) {
            continue;
        }
        let path: Vec<&str> = open.iter().map(|(_, k)| k.as_str()).collect();
        let path = path.join(".");
        let number = value.parse::<usize>().map_err(|_| {
            ImportError::field(
                file,
                format!("{path}.{key}"),
                format!("expected a frame index (a non-negative integer), found {value:?}"),
            )
        })?;
        match blocks.iter_mut().find(|(p, _)| *p == path) {
            Some((_, fields)) => fields[field] = Some(number),
            None => {
                let mut fields = [None; 3];
                fields[field] = Some(number);
                blocks.push((path, fields));
            }
        }
    }
    Ok(blocks)
}

/// The range of `split`: its one block, with `start` and `end`, `skip` at least 1 and
/// `end` at least `start`.
fn split_range(
    blocks: &[(String, Fields)],
    split: &str,
    file: &Path,
) -> Result<Range, ImportError> {
    let mut found = blocks
        .iter()
        .filter(|(p, _)| p.rsplit('.').next() == Some(split));
    let (path, fields) = found.next().ok_or_else(|| {
        ImportError::file(
            file,
            format!(
                "no `{split}:` block with `start` and `end` (expected InstantAvatar's \
                 confs/dataset/peoplesnapshot/<subject>.yaml: opt: {split}: start: N, \
                 end: N, skip: N, one key a line)"
            ),
        )
    })?;
    if let Some((other, _)) = found.next() {
        return Err(ImportError::file(
            file,
            format!("two `{split}:` blocks with frame ranges ({path} and {other})"),
        ));
    }
    let get = |k: usize, name: &str| {
        fields[k].ok_or_else(|| {
            ImportError::field(
                file,
                format!("{path}.{name}"),
                "missing (expected a frame index)",
            )
        })
    };
    let r = Range {
        start: get(0, "start")?,
        end: get(1, "end")?,
        skip: fields[2].unwrap_or(1),
    };
    if r.skip == 0 {
        return Err(ImportError::field(
            file,
            format!("{path}.skip"),
            "expected at least 1, found 0",
        ));
    }
    if r.end < r.start {
        return Err(ImportError::field(
            file,
            format!("{path}.end"),
            format!(
                "expected at least start ({}), found {}: the range is empty",
                r.start, r.end
            ),
        ));
    }
    Ok(r)
}

/// `line` without a YAML comment (`#` at the start or after a space).
fn strip_comment(line: &str) -> &str {
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        if c == '#' && prev.is_whitespace() {
            return &line[..i];
        }
        prev = c;
    }
    line
}

/// [`parse_splits_yaml`] of `file`.
pub(super) fn read_splits_yaml(file: &Path) -> Result<[Range; 3], ImportError> {
    let text = std::fs::read_to_string(file).map_err(ImportError::io(file))?;
    parse_splits_yaml(&text, file)
}
