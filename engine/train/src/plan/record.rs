//! What a plan records: the census and each decision, as `recipe.json` and the
//! checkpoints keep them, and their description for a terminal. Deciding them is the
//! rules' job; this file knows no options.

use serde::{Deserialize, Serialize};
use talkin_data::census::{Census, SubjectCensus};

/// The census and what was decided from it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub census: Census,
    pub decisions: Vec<Decision>,
}

/// One decision.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// The flag that sets it, as typed (`--hands`).
    pub flag: String,
    /// The value the census calls for.
    pub planned: String,
    /// The value the run uses.
    pub used: String,
    /// Whether the command line named the flag (then `used` is its value).
    pub overridden: bool,
    /// Why, in one line, with the census' numbers.
    pub reason: String,
}

impl Plan {
    /// The census and the decisions, for a terminal: one line a subject, one a decision.
    pub fn describe(&self) -> String {
        let mut out = String::from("census of the training frames:\n");
        for s in &self.census.subjects {
            out.push_str(&format!("  {}\n", describe_subject(s)));
        }
        out.push_str("plan:\n");
        for d in &self.decisions {
            let value = if d.overridden {
                format!("{} {} (given; the plan: {})", d.flag, d.used, d.planned)
            } else {
                format!("{} {}", d.flag, d.used)
            };
            out.push_str(&format!("  {value:<28} {}\n", d.reason));
        }
        out
    }
}

/// One subject's census in a line.
fn describe_subject(s: &SubjectCensus) -> String {
    if s.frames == 0 {
        return format!("{}: no training frames", s.name);
    }
    let p = &s.pixels;
    let a = &s.articulation;
    format!(
        "{}: {} frames, {} view(s), a pixel {} on the person; a frame: person {:.0} px, \
         head {:.0} ({:.1}%), hands {:.0}+{:.0} ({:.1}%) [{} labels, {} frames counted]; \
         moves: body {:.1} deg, wrists {:.1}, fingers {:.1}, jaw {:.1}, expression {:.3}",
        s.name,
        s.frames,
        s.views,
        s.footprint_mm
            .map_or("unknown".to_string(), |f| format!("{f:.1} mm")),
        p.person,
        p.head,
        100.0 * p.share(p.head),
        p.left_hand,
        p.right_hand,
        100.0 * p.share(p.hands()),
        match s.labels {
            talkin_data::census::LabelSource::None => "no",
            talkin_data::census::LabelSource::Given => "given",
            talkin_data::census::LabelSource::Derived => "derived",
            talkin_data::census::LabelSource::Mixed => "given and derived",
        },
        s.frames_counted,
        a.body_deg,
        a.wrists_deg,
        a.fingers_deg,
        a.jaw_deg,
        a.expression,
    )
}
