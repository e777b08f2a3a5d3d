//! The SMPL-X model file as distributed (`SMPLX_NEUTRAL.npz`, `SMPLX_MALE.npz`, ...), read
//! as vchoutas/smplx reads it, for what the engine needs from it: the rest-pose joints of
//! a body shape and the mean hand pose. The file is the user's (its licence forbids
//! shipping it); nothing here needs it unless a command is given one.
//!
//! Keys read: `v_template` (V, 3), `shapedirs` (V, 3, S), `J_regressor` (55, V) dense,
//! `kintree_table` (2, 55) (checked against [`PARENTS`]), `hands_meanl` and `hands_meanr`
//! (45,). Other members, including the pickled `joint2num` and `part2num`, are never
//! decoded. Float members may be f4 or f8.
//!
//! `shapedirs` holds the body-shape directions followed by the expression directions:
//! with 400 columns or more (SMPL-X v1.1, 2020) shape is columns 0..300 and expression
//! 300..400; older files have 20 columns, 10 of shape then 10 of expression.

use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::array::{Dim, NdArray};
use crate::npz::{Npz, NpzError};
use talkin_human::body::{N_HAND_JOINTS, N_JOINTS, PARENTS, Skeleton};

/// Shape columns of a full (v1.1) model; expression columns follow.
pub const SHAPE_SPACE_DIM: usize = 300;
/// Expression columns of a full model.
pub const EXPRESSION_SPACE_DIM: usize = 100;

/// Why a model file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Npz(#[from] NpzError),
    #[error(
        "{}: `J_regressor` is pickled (a scipy sparse matrix?): re-save the model with a dense \
         (55, V) float array",
        file.display()
    )]
    SparseRegressor { file: PathBuf },
    #[error(
        "{}: .pkl SMPL-X models (chumpy objects, sparse regressor) are not read: use the .npz \
         model file",
        file.display()
    )]
    PklModel { file: PathBuf },
    #[error(
        "{}: `kintree_table` gives joint {joint} the parent {found}, SMPL-X's is {expected}",
        file.display()
    )]
    Parents {
        file: PathBuf,
        joint: usize,
        found: i64,
        expected: i32,
    },
    #[error(
        "{}: {given} shape coefficients given, the model has {available} shape components",
        file.display()
    )]
    TooManyBetas {
        file: PathBuf,
        given: usize,
        available: usize,
    },
    #[error(
        "{}: {given} expression coefficients given, the model has {available}",
        file.display()
    )]
    TooManyExpressions {
        file: PathBuf,
        given: usize,
        available: usize,
    },
}

/// The parts of an SMPL-X model the engine uses.
#[derive(Clone, Debug)]
pub struct SmplxModel {
    file: PathBuf,
    v_template: Vec<DVec3>,
    /// (V, 3, columns), C order.
    shapedirs: Vec<f64>,
    columns: usize,
    n_shape: usize,
    /// First expression column and count.
    expression: (usize, usize),
    /// (55, V), C order.
    j_regressor: Vec<f64>,
    hands_mean: ([DVec3; N_HAND_JOINTS], [DVec3; N_HAND_JOINTS]),
}

impl SmplxModel {
    /// Reads the model file `path` (an `.npz`).
    pub fn load(path: impl AsRef<Path>) -> Result<SmplxModel, ModelError> {
        let file = path.as_ref().to_path_buf();
        if file
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("pkl"))
        {
            return Err(ModelError::PklModel { file });
        }
        let mut npz = Npz::open(&file)?;
        let v = npz.read_checked("v_template", &[Dim::Any("V"), Dim::Is(3)])?;
        let n_v = v.shape()[0];
        let shapedirs =
            npz.read_checked("shapedirs", &[Dim::Is(n_v), Dim::Is(3), Dim::Any("S")])?;
        let columns = shapedirs.shape()[2];
        let j_regressor = match npz.read_checked("J_regressor", &[Dim::Is(N_JOINTS), Dim::Is(n_v)])
        {
            Err(NpzError::Pickled { .. }) => return Err(ModelError::SparseRegressor { file }),
            r => r?,
        };
        let kintree = npz.read_checked("kintree_table", &[Dim::Is(2), Dim::Is(N_JOINTS)])?;
        let parents = floats(&kintree);
        for j in 1..N_JOINTS {
            if parents[j] != f64::from(PARENTS[j]) {
                return Err(ModelError::Parents {
                    file,
                    joint: j,
                    found: parents[j] as i64,
                    expected: PARENTS[j],
                });
            }
        }
        let hand = |npz: &mut Npz, key: &str| -> Result<[DVec3; N_HAND_JOINTS], ModelError> {
            let a = npz.read_checked(key, &[Dim::Is(3 * N_HAND_JOINTS)])?;
            let x = floats(&a);
            Ok(std::array::from_fn(|j| {
                DVec3::new(x[3 * j], x[3 * j + 1], x[3 * j + 2])
            }))
        };
        let hands_mean = (
            hand(&mut npz, "hands_meanl")?,
            hand(&mut npz, "hands_meanr")?,
        );
        let (n_shape, expression) = split_columns(columns);
        let vt = floats(&v);
        Ok(SmplxModel {
            file,
            v_template: vt
                .chunks_exact(3)
                .map(|c| DVec3::new(c[0], c[1], c[2]))
                .collect(),
            shapedirs: floats(&shapedirs),
            columns,
            n_shape,
            expression,
            j_regressor: floats(&j_regressor),
            hands_mean,
        })
    }

    /// The file it was read from.
    pub fn file(&self) -> &Path {
        &self.file
    }

    /// Vertices of the template mesh.
    pub fn n_vertices(&self) -> usize {
        self.v_template.len()
    }

    /// Body-shape coefficients the model has (300, or 10 in old files).
    pub fn n_shape(&self) -> usize {
        self.n_shape
    }

    /// Expression coefficients the model has (100, or 10 in old files).
    pub fn n_expression(&self) -> usize {
        self.expression.1
    }

    /// Rest-pose (T-pose) joints of body shape `betas` (any length up to
    /// [`Self::n_shape`]; missing coefficients are zero) with a neutral face:
    /// `J_regressor (v_template + shapedirs[:, :, :len(betas)] betas)`.
    pub fn rest_joints(&self, betas: &[f64]) -> Result<[DVec3; N_JOINTS], ModelError> {
        self.rest_joints_with_expression(betas, &[])
    }

    /// Rest-pose joints of shape `betas` and expression `expression` (the expression moves
    /// the face's vertices and so, slightly, the joints the regressor averages them into).
    pub fn rest_joints_with_expression(
        &self,
        betas: &[f64],
        expression: &[f64],
    ) -> Result<[DVec3; N_JOINTS], ModelError> {
        if betas.len() > self.n_shape {
            return Err(ModelError::TooManyBetas {
                file: self.file.clone(),
                given: betas.len(),
                available: self.n_shape,
            });
        }
        if expression.len() > self.expression.1 {
            return Err(ModelError::TooManyExpressions {
                file: self.file.clone(),
                given: expression.len(),
                available: self.expression.1,
            });
        }
        let coefficients: Vec<(usize, f64)> = betas
            .iter()
            .copied()
            .enumerate()
            .chain(
                expression
                    .iter()
                    .enumerate()
                    .map(|(k, &e)| (self.expression.0 + k, e)),
            )
            .filter(|&(_, c)| c != 0.0)
            .collect();
        let shaped: Vec<DVec3> = self
            .v_template
            .iter()
            .enumerate()
            .map(|(v, &t)| {
                let row = |k: usize| &self.shapedirs[(v * 3 + k) * self.columns..][..self.columns];
                let (x, y, z) = (row(0), row(1), row(2));
                coefficients
                    .iter()
                    .fold(t, |p, &(c, b)| p + DVec3::new(x[c], y[c], z[c]) * b)
            })
            .collect();
        let n_v = self.v_template.len();
        Ok(std::array::from_fn(|j| {
            let weights = &self.j_regressor[j * n_v..(j + 1) * n_v];
            weights
                .iter()
                .zip(&shaped)
                .filter(|(w, _)| **w != 0.0)
                .fold(DVec3::ZERO, |acc, (&w, &p)| acc + p * w)
        }))
    }

    /// The skeleton of body shape `betas`.
    pub fn skeleton(&self, betas: &[f64]) -> Result<Skeleton, ModelError> {
        Ok(Skeleton {
            rest_joints: self.rest_joints(betas)?,
        })
    }

    /// The mean hand pose (left, right): axis-angle per finger joint, added to hand poses
    /// stored relative to it (`flat_hand_mean=False`).
    pub fn hands_mean(&self) -> ([DVec3; N_HAND_JOINTS], [DVec3; N_HAND_JOINTS]) {
        self.hands_mean
    }
}

/// Shape columns and (first column, count) of expression columns of a `shapedirs` with
/// `columns` columns, as vchoutas/smplx splits it.
fn split_columns(columns: usize) -> (usize, (usize, usize)) {
    if columns >= SHAPE_SPACE_DIM + EXPRESSION_SPACE_DIM {
        (SHAPE_SPACE_DIM, (SHAPE_SPACE_DIM, EXPRESSION_SPACE_DIM))
    } else if columns >= 20 {
        // SMPL-X v1.0: 10 shape then 10 expression columns.
        (10, (10, 10))
    } else {
        (columns, (columns, 0))
    }
}

/// A checked numeric array's values as f64 (it holds numbers, so this cannot fail).
fn floats(a: &NdArray) -> Vec<f64> {
    a.to_f64().unwrap_or_default()
}

/// A small model file of the real layout (keys, dtypes, an object member to skip), for
/// tests here and in the crates that read the model through this one (the `fixtures`
/// feature): the SMPL-X model is the user's and is never shipped.
#[cfg(any(test, feature = "fixtures"))]
pub mod fixture {
    use super::*;
    use crate::array::ArrayData;
    use crate::npz::{NpzWriter, object_npy_bytes};

    /// Vertices and shape components of the fixture.
    pub const V: usize = 64;
    pub const S: usize = 20;

    /// What the fixture file holds, to check a reader against.
    pub struct Fixture {
        pub v_template: Vec<f64>,
        pub shapedirs: Vec<f64>,
        pub j_regressor: Vec<f64>,
    }

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    }

    /// Writes the fixture model to `file` with the kinematic tree `parents`.
    pub fn write_fixture(file: &Path, parents: &[i32; N_JOINTS]) -> Fixture {
        let mut seed = 7;
        let v_template: Vec<f64> = (0..V * 3).map(|_| lcg(&mut seed)).collect();
        let shapedirs: Vec<f64> = (0..V * 3 * S).map(|_| 0.01 * lcg(&mut seed)).collect();
        // Each joint averages four vertices (rows sum to 1), like the real regressor.
        let mut j_regressor = vec![0.0; N_JOINTS * V];
        for j in 0..N_JOINTS {
            for k in 0..4 {
                j_regressor[j * V + (j * 3 + k * 5) % V] += 0.25;
            }
        }
        let mut kintree: Vec<u32> = parents.iter().map(|&p| p as u32).collect();
        kintree.extend(0..N_JOINTS as u32);
        let mut w = NpzWriter::create(file).unwrap();
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        w.array(
            "v_template",
            &NdArray::f64(&[V, 3], v_template.clone()).unwrap(),
        )
        .unwrap()
        .array(
            "shapedirs",
            &NdArray::f32(&[V, 3, S], f32s(&shapedirs)).unwrap(),
        )
        .unwrap()
        .array(
            "J_regressor",
            &NdArray::f64(&[N_JOINTS, V], j_regressor.clone()).unwrap(),
        )
        .unwrap()
        .array(
            "kintree_table",
            &NdArray::new(vec![2, N_JOINTS], ArrayData::U32(kintree)).unwrap(),
        )
        .unwrap()
        .array(
            "hands_meanl",
            &NdArray::f32(&[45], (0..45).map(|i| i as f32 * 0.01).collect()).unwrap(),
        )
        .unwrap()
        .array(
            "hands_meanr",
            &NdArray::f32(&[45], (0..45).map(|i| -(i as f32) * 0.01).collect()).unwrap(),
        )
        .unwrap()
        .array(
            "f",
            &NdArray::new(vec![2, 3], ArrayData::I32(vec![0, 1, 2, 2, 1, 3])).unwrap(),
        )
        .unwrap()
        .raw("joint2num", &object_npy_bytes(b"\x80\x02}q\x00."))
        .unwrap();
        w.finish().unwrap();
        Fixture {
            // shapedirs went through f32.
            shapedirs: shapedirs.iter().map(|&x| f64::from(x as f32)).collect(),
            v_template,
            j_regressor,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::fixture::*;
    use super::*;
    use crate::npz::{NpzWriter, object_npy_bytes};

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("talkin_smplx_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn rest_joints_match_a_direct_computation() {
        let file = temp("SMPLX_NEUTRAL.npz");
        let fx = write_fixture(&file, &PARENTS);
        let model = SmplxModel::load(&file).unwrap();
        assert_eq!(
            (model.n_vertices(), model.n_shape(), model.n_expression()),
            (V, 10, 10)
        );
        let betas = [0.5, -1.0, 2.0, 0.25];
        let j = model.rest_joints(&betas).unwrap();
        for joint in 0..N_JOINTS {
            let mut want = DVec3::ZERO;
            for v in 0..V {
                let w = fx.j_regressor[joint * V + v];
                let mut p = [0.0; 3];
                for k in 0..3 {
                    p[k] = fx.v_template[v * 3 + k];
                    for (b, beta) in betas.iter().enumerate() {
                        p[k] += fx.shapedirs[(v * 3 + k) * S + b] * beta;
                    }
                }
                want += DVec3::from_array(p) * w;
            }
            assert!((j[joint] - want).length() < 1e-12, "joint {joint}");
        }
        // Expression columns start at 10 in a 20-column file.
        let e = model.rest_joints_with_expression(&[], &[1.0]).unwrap();
        let base = model.rest_joints(&[]).unwrap();
        let mut moved = DVec3::ZERO;
        for v in 0..V {
            let d = DVec3::new(
                fx.shapedirs[v * 3 * S + 10],
                fx.shapedirs[(v * 3 + 1) * S + 10],
                fx.shapedirs[(v * 3 + 2) * S + 10],
            );
            moved += d * fx.j_regressor[v];
        }
        assert!((e[0] - base[0] - moved).length() < 1e-12);
        let e = model.rest_joints(&[0.0; 11]).unwrap_err().to_string();
        assert!(
            e.contains("11 shape coefficients") && e.contains("10 shape components"),
            "{e}"
        );
        let (l, r) = model.hands_mean();
        assert!((l[1] - DVec3::new(0.03, 0.04, 0.05)).length() < 1e-6);
        assert!((r[14].z + 0.44).abs() < 1e-6);
        assert_eq!(split_columns(400), (300, (300, 100)));
    }

    #[test]
    fn missing_keys_wrong_shapes_and_bad_parents_are_named() {
        let mut parents = PARENTS;
        parents[30] = 28;
        let file = temp("bad_parents.npz");
        write_fixture(&file, &parents);
        let e = SmplxModel::load(&file).unwrap_err().to_string();
        assert!(
            e.contains("bad_parents.npz")
                && e.contains("joint 30 the parent 28")
                && e.contains("is 29"),
            "{e}"
        );
        let file = temp("no_hands.npz");
        let bad = temp("bad_regressor.npz");
        {
            let mut w = NpzWriter::create(&bad).unwrap();
            w.array(
                "v_template",
                &NdArray::f64(&[V, 3], vec![0.0; V * 3]).unwrap(),
            )
            .unwrap()
            .array(
                "shapedirs",
                &NdArray::f64(&[V, 3, 2], vec![0.0; V * 6]).unwrap(),
            )
            .unwrap()
            .array(
                "J_regressor",
                &NdArray::f64(&[N_JOINTS, V - 1], vec![0.0; N_JOINTS * (V - 1)]).unwrap(),
            )
            .unwrap();
            w.finish().unwrap();
        }
        let e = SmplxModel::load(&bad).unwrap_err().to_string();
        assert!(
            e.contains("bad_regressor.npz")
                && e.contains("`J_regressor`")
                && e.contains("(55, 64)"),
            "{e}"
        );
        {
            let mut w = NpzWriter::create(&file).unwrap();
            w.array(
                "v_template",
                &NdArray::f64(&[V, 3], vec![0.0; V * 3]).unwrap(),
            )
            .unwrap();
            w.finish().unwrap();
        }
        let e = SmplxModel::load(&file).unwrap_err().to_string();
        assert!(
            e.contains("no_hands.npz")
                && e.contains("`shapedirs` is missing")
                && e.contains("(64, 3, S)"),
            "{e}"
        );
        let sparse = temp("sparse.npz");
        {
            let mut w = NpzWriter::create(&sparse).unwrap();
            w.array(
                "v_template",
                &NdArray::f64(&[V, 3], vec![0.0; V * 3]).unwrap(),
            )
            .unwrap()
            .array(
                "shapedirs",
                &NdArray::f64(&[V, 3, 2], vec![0.0; V * 6]).unwrap(),
            )
            .unwrap()
            .raw("J_regressor", &object_npy_bytes(b"\x80\x02N."))
            .unwrap();
            w.finish().unwrap();
        }
        assert!(matches!(
            SmplxModel::load(&sparse),
            Err(ModelError::SparseRegressor { .. })
        ));
        assert!(matches!(
            SmplxModel::load(temp("SMPLX_NEUTRAL.pkl")),
            Err(ModelError::PklModel { .. })
        ));
    }
}
