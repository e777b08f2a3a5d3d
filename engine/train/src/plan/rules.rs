//! The plan's rules: from the census to each setting, with its reason. The thresholds
//! and how they were measured are in docs/design.md ("A plan from the data").

use talkin_data::census::{Census, SubjectCensus};

use super::{Choice, Setting};
use crate::preset::Preset;
use crate::recipe::{FingerSkinning, TrainOptions};
use talkin_nets::encoding::{EncodingConfig, HashGridConfig};

/// Where a part or an input stops paying for itself.
#[derive(Clone, Debug, PartialEq)]
pub struct Thresholds {
    /// Mean pixels a frame of both hands below which the finger bones and D_hands are
    /// off: too few pixels to teach a finger.
    pub hands_min_px: f64,
    /// Spread of the fingers' fitted rotations (degrees, the widest joint) below which the
    /// finger bones and D_hands are off: the fingers keep one pose, which the wrist
    /// carries.
    pub fingers_min_deg: f64,
    /// Spread of the jaw's rotation (degrees) below which F_face does not read it.
    pub jaw_min_deg: f64,
    /// Standard deviation of an expression coefficient below which F_face does not read
    /// the expression.
    pub expression_min: f64,
    /// The finest hash level's cell as a fraction of the pixel's footprint on the person.
    pub finest_cell_of_footprint: f64,
    /// The same on a capture, whose fits misalign the frames by more than a pixel: a cell
    /// finer than that is taught each frame's misalignment, and renders it as speckle.
    pub finest_cell_of_footprint_capture: f64,
}

impl Thresholds {
    /// The thresholds the plan uses (docs/design.md, "A plan from the data").
    pub const MEASURED: Thresholds = Thresholds {
        hands_min_px: 100.0,
        fingers_min_deg: 1.0,
        jaw_min_deg: 0.5,
        expression_min: 0.01,
        finest_cell_of_footprint: 0.25,
        finest_cell_of_footprint_capture: 1.5,
    };
}

/// A setting and how the census chooses it (`None`: the rule does not apply, as the hash
/// grid's size under the `paper` preset).
pub(super) struct Rule {
    pub setting: Setting,
    pub choose: fn(&Census, &TrainOptions, &Thresholds) -> Option<(Choice, String)>,
}

fn on_off(b: bool) -> String {
    if b { "on" } else { "off" }.to_string()
}

/// The largest of `f` over the subjects with frames (0 without any).
/// An input F_face reads only where it moves (`moved`, described by `moves`), and only
/// when the run has F_face.
fn face_input(
    opts: &TrainOptions,
    input: &str,
    moved: bool,
    moves: String,
) -> Option<(Choice, String)> {
    let on = opts.ablation.face && moved;
    let seen = if opts.ablation.face {
        moves
    } else {
        "no F_face".into()
    };
    Some((
        Choice::Switch(on),
        format!("{input}: {seen}: F_face reads it {}", on_off(on)),
    ))
}

fn widest(census: &Census, f: impl Fn(&SubjectCensus) -> f64) -> f64 {
    census.present().map(f).fold(0.0, f64::max)
}

/// The `fast` preset's F_body hash grid, which the plan sizes down from: it goes no finer
/// than the CPU-sized preset (the demo's footprint asks for exactly its levels and table).
fn preset_grid() -> HashGridConfig {
    match Preset::Fast.field_config(1).encoding {
        EncodingConfig::HashGrid(grid) => grid,
        _ => unreachable!("the fast preset encodes with a hash grid"),
    }
}
/// The smallest the plan makes them.
const MIN_LEVELS: usize = 8;
const MIN_TABLE_LOG2: usize = 14;
/// The field's box around the canonical capsules (the occupancy grid's margin and the
/// box's padding), metres a side.
const BOX_MARGIN_M: f64 = 0.15;

/// What sizes the fast preset's hash grid, in metres: the finest cell the data can teach
/// and the side of the field's box. `None` for another preset (the plan leaves its grid
/// alone); `Some(None)` without a footprint.
fn grid_need(census: &Census, opts: &TrainOptions, t: &Thresholds) -> Option<Option<(f64, f64)>> {
    (opts.preset == Preset::Fast).then(|| {
        let side = widest(census, |s| s.canonical.extent_m) + BOX_MARGIN_M;
        finest_cell_m(census, t).map(|cell| (cell, side))
    })
}

/// The finest cell the data can teach (metres): a fraction of the smallest footprint of
/// any subject, a larger one on a capture; `None` without a footprint.
fn finest_cell_m(census: &Census, t: &Thresholds) -> Option<f64> {
    census
        .present()
        .filter_map(|s| s.footprint_mm)
        .filter(|f| f.is_finite() && *f > 0.0)
        .min_by(f64::total_cmp)
        .map(|f| f * 1e-3 * cell_of_footprint(census, t))
}

/// The finest cell as a fraction of the footprint, for this census.
fn cell_of_footprint(census: &Census, t: &Thresholds) -> f64 {
    if census.capture {
        t.finest_cell_of_footprint_capture
    } else {
        t.finest_cell_of_footprint
    }
}

pub(super) const RULES: [Rule; 8] = [
    Rule {
        setting: Setting {
            flag: "--hands",
            id: "hands",
            get: |o| on_off(o.ablation.hands),
            set: |o, c| {
                if let Choice::Switch(b) = c {
                    o.ablation.hands = *b;
                }
            },
        },
        choose: |census, _, _| {
            let px = widest(census, |s| s.pixels.hands());
            let share = widest(census, |s| s.pixels.share(s.pixels.hands()));
            // Kept whatever the hands show: without F_hands a scene whose hands never
            // show lost 0.7 dB at equal steps (docs/design.md, "A plan from the data").
            Some((
                Choice::Switch(true),
                format!(
                    "hands: {px:.0} px a frame ({:.1}% of the person){}: F_hands kept \
                     (without it, runs lost 0.7 dB even where no hand shows)",
                    100.0 * share,
                    shown_in(census, |s| s.pixels.frames_with_hands),
                ),
            ))
        },
    },
    Rule {
        setting: Setting {
            flag: "--skin-fingers",
            id: "skin_fingers",
            get: |o| match o.skin_fingers {
                FingerSkinning::Bones => "bones".into(),
                FingerSkinning::Wrist => "wrist".into(),
            },
            set: |o, c| {
                if let Choice::Fingers(f) = c {
                    o.skin_fingers = *f;
                }
            },
        },
        choose: |census, opts, t| {
            let deg = widest(census, |s| s.articulation.fingers_deg);
            let seen = widest(census, |s| s.pixels.hands()) >= t.hands_min_px;
            let bones = opts.ablation.hands && seen && deg >= t.fingers_min_deg;
            let reason = if !opts.ablation.hands {
                format!(
                    "fingers: no F_hands to learn them (they move {deg:.1} deg): finger bones off"
                )
            } else {
                format!(
                    "fingers: move {deg:.1} deg (RMS, widest joint): finger bones {}",
                    if bones {
                        "on".to_string()
                    } else if !seen {
                        format!(
                            "off (the hands show under {:.0} px a frame)",
                            t.hands_min_px
                        )
                    } else {
                        format!("off (under {} deg)", t.fingers_min_deg)
                    }
                )
            };
            let fingers = if bones {
                FingerSkinning::Bones
            } else {
                FingerSkinning::Wrist
            };
            Some((Choice::Fingers(fingers), reason))
        },
    },
    Rule {
        setting: Setting {
            flag: "--hand-deform",
            id: "use_d_hands",
            get: |o| on_off(o.ablation.use_d_hands && o.ablation.hands),
            set: |o, c| {
                if let Choice::Switch(b) = c {
                    o.ablation.use_d_hands = *b;
                }
            },
        },
        choose: |census, opts, t| {
            let deg = widest(census, |s| s.articulation.fingers_deg);
            let seen = widest(census, |s| s.pixels.hands()) >= t.hands_min_px;
            let on = opts.ablation.hands && seen && deg >= t.fingers_min_deg;
            Some((
                Choice::Switch(on),
                format!(
                    "D_hands: reads the hand pose, {}: {}",
                    if opts.ablation.hands {
                        format!("which moves {deg:.1} deg")
                    } else {
                        "no F_hands".into()
                    },
                    on_off(on)
                ),
            ))
        },
    },
    Rule {
        setting: Setting {
            flag: "--face",
            id: "face",
            get: |o| on_off(o.ablation.face),
            set: |o, c| {
                if let Choice::Switch(b) = c {
                    o.ablation.face = *b;
                }
            },
        },
        choose: |census, _, _| {
            let px = widest(census, |s| s.pixels.head);
            let share = widest(census, |s| s.pixels.share(s.pixels.head));
            // Kept, as F_hands is: both take part in the occupancy grid's updates, and
            // dropping F_hands cost even scenes that never show a hand.
            Some((
                Choice::Switch(true),
                format!(
                    "head: {px:.0} px a frame ({:.1}% of the person){}: F_face kept",
                    100.0 * share,
                    shown_in(census, |s| s.pixels.frames_with_head),
                ),
            ))
        },
    },
    Rule {
        setting: Setting {
            flag: "--face-expression",
            id: "face_uses_expression",
            get: |o| on_off(o.ablation.face_uses_expression && o.ablation.face),
            set: |o, c| {
                if let Choice::Switch(b) = c {
                    o.ablation.face_uses_expression = *b;
                }
            },
        },
        choose: |census, opts, t| {
            let sd = widest(census, |s| s.articulation.expression);
            let moves = format!("moves {sd:.3} (SD, widest coefficient)");
            face_input(opts, "expression", sd >= t.expression_min, moves)
        },
    },
    Rule {
        setting: Setting {
            flag: "--face-jaw",
            id: "face_uses_jaw",
            get: |o| on_off(o.ablation.face_uses_jaw && o.ablation.face),
            set: |o, c| {
                if let Choice::Switch(b) = c {
                    o.ablation.face_uses_jaw = *b;
                }
            },
        },
        choose: |census, opts, t| {
            let deg = widest(census, |s| s.articulation.jaw_deg);
            face_input(
                opts,
                "jaw",
                deg >= t.jaw_min_deg,
                format!("moves {deg:.1} deg"),
            )
        },
    },
    Rule {
        setting: Setting {
            flag: "--hash-levels",
            id: "hash_levels",
            get: |o| {
                o.hash_levels
                    .map_or(format!("{} (preset)", preset_grid().n_levels), |n| {
                        n.to_string()
                    })
            },
            set: |o, c| {
                if let Choice::Count(n) = c {
                    o.hash_levels = Some(*n);
                }
            },
        },
        choose: |census, opts, t| {
            let preset = preset_grid();
            let most = preset.n_levels;
            let Some((cell, side)) = grid_need(census, opts, t)? else {
                return Some((
                    Choice::Count(most),
                    "levels: no footprint to size them: the preset's".into(),
                ));
            };
            let needed = 1.0
                + ((side / cell / preset.base_resolution as f64).ln()
                    / preset.per_level_scale.ln())
                .ceil();
            let levels = if needed.is_finite() {
                (needed.max(0.0) as usize).clamp(MIN_LEVELS, most)
            } else {
                most
            };
            Some((
                Choice::Count(levels),
                format!(
                    "grid: a pixel spans {:.1} mm on the person{}, so the finest cell is {:.1} mm over a {side:.2} m box: {levels} levels{}",
                    cell * 1e3 / cell_of_footprint(census, t),
                    if census.capture {
                        " and a capture's fits misalign frames by more"
                    } else {
                        ""
                    },
                    cell * 1e3,
                    if levels == most && needed > most as f64 {
                        " (the preset's most)"
                    } else {
                        ""
                    }
                ),
            ))
        },
    },
    Rule {
        setting: Setting {
            flag: "--hash-table",
            id: "hash_table_log2",
            get: |o| {
                o.hash_table_log2.map_or(
                    format!("{} (preset)", preset_grid().log2_hashmap_size),
                    |n| n.to_string(),
                )
            },
            set: |o, c| {
                if let Choice::Count(n) = c {
                    o.hash_table_log2 = Some(*n);
                }
            },
        },
        choose: |census, opts, t| {
            let preset = preset_grid();
            let most = preset.log2_hashmap_size;
            let Some((cell, side)) = grid_need(census, opts, t)? else {
                return Some((
                    Choice::Count(most),
                    "table: no footprint to size it: the preset's".into(),
                ));
            };
            // The finest level used (levels above it are not built): its cell.
            let levels = opts.hash_levels.unwrap_or(preset.n_levels);
            let finest = side
                / (preset.base_resolution as f64 * preset.per_level_scale.powi(levels as i32 - 1));
            let cell = cell.max(finest);
            let surface = widest(census, |s| s.canonical.surface_m2);
            let cells = surface / (cell * cell);
            let log2 = if cells.is_finite() && cells >= 1.0 {
                (cells.log2().ceil() as usize).clamp(MIN_TABLE_LOG2, most)
            } else {
                most
            };
            Some((
                Choice::Count(log2),
                format!(
                    "table: {surface:.2} m2 of body surface in {:.1} mm cells is {:.0}k cells a level: 2^{log2} entries{}",
                    cell * 1e3,
                    cells / 1e3,
                    if log2 == most && cells > (1u64 << most) as f64 {
                        " (the preset's most)"
                    } else {
                        ""
                    }
                ),
            ))
        },
    },
];

/// ", in k of n counted frames" where a part does not show in every counted frame.
fn shown_in(census: &Census, frames: impl Fn(&SubjectCensus) -> usize) -> String {
    let (shown, counted) = census
        .present()
        .fold((0, 0), |(a, b), s| (a + frames(s), b + s.frames_counted));
    if shown == counted {
        String::new()
    } else {
        format!(", in {shown} of {counted} counted frames")
    }
}
