//! `--hash-levels` and `--hash-table`: the size of the `fast` preset's hash grids.

use talkin_nets::FieldConfig;
use talkin_nets::encoding::EncodingConfig;

use super::TrainOptions;
use crate::preset::Preset;

/// The levels `--hash-levels` takes.
pub const HASH_LEVELS: std::ops::RangeInclusive<usize> = 4..=16;

/// The table sizes (log2 entries a level) `--hash-table` takes.
pub const HASH_TABLE_LOG2: std::ops::RangeInclusive<usize> = 12..=22;

/// How many entries F_face's and F_hands' tables hold fewer than F_body's, as a power of
/// two (the preset's 2^15 against 2^17).
const PART_TABLE_SHIFT: usize = 2;

impl TrainOptions {
    /// Sets the hash grids' levels and table sizes of `config` where the options name
    /// them; the preset's otherwise.
    pub fn apply_hash_grid(&self, config: &mut FieldConfig) {
        let set = |encoding: &mut EncodingConfig, table_shift: usize| {
            if let EncodingConfig::HashGrid(grid) = encoding {
                if let Some(levels) = self.hash_levels {
                    grid.n_levels = levels;
                }
                if let Some(log2) = self.hash_table_log2 {
                    grid.log2_hashmap_size = log2 - table_shift;
                }
            }
        };
        set(&mut config.encoding, 0);
        if let Some(part) = &mut config.part_encoding {
            set(part, PART_TABLE_SHIFT);
        }
    }

    /// `--hash-levels` and `--hash-table` in range, and only with a hash grid.
    pub(super) fn check_hash_grid(&self) -> Result<(), (&'static str, String)> {
        for (flag, value, range) in [
            ("--hash-levels", self.hash_levels, HASH_LEVELS),
            ("--hash-table", self.hash_table_log2, HASH_TABLE_LOG2),
        ] {
            let Some(v) = value else { continue };
            if self.preset != Preset::Fast {
                return Err((
                    flag,
                    format!("the `{}` preset has no hash grid", self.preset),
                ));
            }
            if !range.contains(&v) {
                return Err((
                    flag,
                    format!("must be in {}..={}", range.start(), range.end()),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flags_size_every_table_and_default_to_the_presets() {
        let preset = Preset::Fast.field_config(1);
        let mut config = preset.clone();
        TrainOptions::default().apply_hash_grid(&mut config);
        assert_eq!(format!("{config:?}"), format!("{preset:?}"));
        let opts = TrainOptions {
            hash_levels: Some(10),
            hash_table_log2: Some(16),
            ..TrainOptions::default()
        };
        assert!(opts.check_hash_grid().is_ok());
        opts.apply_hash_grid(&mut config);
        let grid = |e: &EncodingConfig| match e {
            EncodingConfig::HashGrid(g) => (g.n_levels, g.log2_hashmap_size),
            _ => panic!(),
        };
        assert_eq!(grid(&config.encoding), (10, 16));
        assert_eq!(grid(config.part_encoding.as_ref().unwrap()), (10, 14));
        for bad in [
            TrainOptions {
                hash_levels: Some(3),
                ..TrainOptions::default()
            },
            TrainOptions {
                hash_table_log2: Some(23),
                ..TrainOptions::default()
            },
            TrainOptions {
                preset: Preset::Paper,
                hash_levels: Some(12),
                ..TrainOptions::default()
            },
        ] {
            assert!(bad.check_hash_grid().is_err());
        }
    }
}
