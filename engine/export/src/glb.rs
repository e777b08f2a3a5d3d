//! The glTF 2.0 document of an exported avatar and its binary container: one buffer in
//! the GLB's BIN chunk; a mesh with positions, normals, vertex colours (unlit: the
//! colours are the field's radiance, lighting is already in them), joints and weights; a
//! skin over the 55 joint nodes (node `j` is SMPL-X joint `j`); and, with a motion, one
//! animation with a rotation channel per joint and the root's translation. The document
//! is built with `gltf-json`'s types and framed by `gltf`'s GLB writer.

use std::borrow::Cow;
use std::collections::BTreeMap;

use glam::{Mat4, Vec3};
use gltf::json::{self as gj, Index, validation::Checked::Valid, validation::USize64};
use talkin_human::body::N_JOINTS;

use crate::animation::Keyframes;
use crate::rig::Rig;
use crate::{ExportError, ExportedAvatar};

/// The node of the skinned mesh (after the joints).
const MESH_NODE: u32 = N_JOINTS as u32;

/// The avatar's GLB bytes; `keys` adds its animation.
pub fn to_glb(avatar: &ExportedAvatar, keys: Option<&Keyframes>) -> Result<Vec<u8>, ExportError> {
    let mut doc = Document::default();
    let mesh = doc.mesh(avatar);
    let skin = doc.skin(&avatar.rig);
    doc.nodes(&avatar.rig, mesh, skin, &avatar.subject);
    if let Some(keys) = keys {
        doc.animation(keys);
    }
    doc.finish()
}

/// A document and its binary buffer as they are built.
#[derive(Default)]
struct Document {
    root: gj::Root,
    bin: Vec<u8>,
}

impl Document {
    /// Appends `bytes` as a buffer view (4-byte aligned).
    fn view(
        &mut self,
        bytes: &[u8],
        target: Option<gj::buffer::Target>,
    ) -> Index<gj::buffer::View> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.root.push(gj::buffer::View {
            buffer: Index::new(0),
            byte_length: USize64::from(bytes.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Valid),
            extensions: Default::default(),
            extras: Default::default(),
        })
    }

    /// An accessor of `count` elements of `type_` in their own view.
    #[allow(clippy::too_many_arguments)]
    fn accessor(
        &mut self,
        bytes: &[u8],
        count: usize,
        component: gj::accessor::ComponentType,
        type_: gj::accessor::Type,
        target: Option<gj::buffer::Target>,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
    ) -> Index<gj::Accessor> {
        let view = self.view(bytes, target);
        let (min, max) = match bounds {
            Some((lo, hi)) => (Some(lo.into()), Some(hi.into())),
            None => (None, None),
        };
        self.root.push(gj::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(gj::accessor::GenericComponentType(component)),
            extensions: Default::default(),
            extras: Default::default(),
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn floats<const N: usize>(
        &mut self,
        values: &[[f32; N]],
        type_: gj::accessor::Type,
        target: Option<gj::buffer::Target>,
        with_bounds: bool,
    ) -> Index<gj::Accessor> {
        let bytes: Vec<u8> = values
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let bounds = with_bounds.then(|| {
            let lo = (0..N)
                .map(|k| values.iter().map(|v| v[k]).fold(f32::INFINITY, f32::min))
                .collect();
            let hi = (0..N)
                .map(|k| {
                    values
                        .iter()
                        .map(|v| v[k])
                        .fold(f32::NEG_INFINITY, f32::max)
                })
                .collect();
            (lo, hi)
        });
        let component = gj::accessor::ComponentType::F32;
        self.accessor(&bytes, values.len(), component, type_, target, bounds)
    }

    fn mesh(&mut self, avatar: &ExportedAvatar) -> Index<gj::Mesh> {
        use gj::accessor::{ComponentType, Type};
        use gj::buffer::Target::{ArrayBuffer, ElementArrayBuffer};
        use gj::mesh::Semantic;
        let s = &avatar.surface;
        let positions: Vec<[f32; 3]> = s.positions.iter().map(|p| p.to_array()).collect();
        let normals: Vec<[f32; 3]> = s.normals.iter().map(|p| p.to_array()).collect();
        let mut attributes = BTreeMap::new();
        let vertex = Some(ArrayBuffer);
        let position = self.floats(&positions, Type::Vec3, vertex, true);
        attributes.insert(Valid(Semantic::Positions), position);
        let normal = self.floats(&normals, Type::Vec3, vertex, false);
        attributes.insert(Valid(Semantic::Normals), normal);
        let colour = self.floats(&avatar.colours, Type::Vec3, vertex, false);
        attributes.insert(Valid(Semantic::Colors(0)), colour);
        let joints: Vec<u8> = avatar.skin.joints.iter().flatten().copied().collect();
        let n = s.positions.len();
        let joints = self.accessor(&joints, n, ComponentType::U8, Type::Vec4, vertex, None);
        attributes.insert(Valid(Semantic::Joints(0)), joints);
        let weights = self.floats(&avatar.skin.weights, Type::Vec4, vertex, false);
        attributes.insert(Valid(Semantic::Weights(0)), weights);
        let indices: Vec<u8> = s
            .triangles
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let count = 3 * s.triangles.len();
        let indices = self.accessor(
            &indices,
            count,
            ComponentType::U32,
            Type::Scalar,
            Some(ElementArrayBuffer),
            None,
        );
        let material = self.root.push(gj::Material {
            name: Some("field radiance (unlit vertex colours)".into()),
            extensions: Some(gj::extensions::material::Material {
                unlit: Some(gj::extensions::material::Unlit {}),
            }),
            ..Default::default()
        });
        self.root
            .extensions_used
            .push("KHR_materials_unlit".to_string());
        self.root.push(gj::Mesh {
            extensions: Default::default(),
            extras: Default::default(),
            name: Some(avatar.subject.clone()),
            primitives: vec![gj::mesh::Primitive {
                attributes,
                extensions: Default::default(),
                extras: Default::default(),
                indices: Some(indices),
                material: Some(material),
                mode: Valid(gj::mesh::Mode::Triangles),
                targets: None,
            }],
            weights: None,
        })
    }

    fn skin(&mut self, rig: &Rig) -> Index<gj::Skin> {
        let matrices: Vec<[f32; 16]> = rig.inverse_bind.iter().map(Mat4::to_cols_array).collect();
        let ibm = self.floats(&matrices, gj::accessor::Type::Mat4, None, false);
        self.root.push(gj::Skin {
            extensions: Default::default(),
            extras: Default::default(),
            inverse_bind_matrices: Some(ibm),
            joints: (0..N_JOINTS as u32).map(Index::new).collect(),
            name: Some("SMPL-X".into()),
            skeleton: Some(Index::new(0)),
        })
    }

    /// The joint nodes (0..55, bind pose) and the mesh's node, and the scene of both.
    fn nodes(&mut self, rig: &Rig, mesh: Index<gj::Mesh>, skin: Index<gj::Skin>, name: &str) {
        for j in 0..N_JOINTS {
            let children: Vec<Index<gj::Node>> = (0..N_JOINTS)
                .filter(|&c| Rig::parent(c) == Some(j))
                .map(|c| Index::new(c as u32))
                .collect();
            let pose = rig.bind[j];
            self.root.push(gj::Node {
                children: (!children.is_empty()).then_some(children),
                name: Some(Rig::name(j).to_string()),
                rotation: Some(gj::scene::UnitQuaternion(pose.rotation.to_array())),
                translation: Some(pose.translation.to_array()),
                ..Default::default()
            });
        }
        let node = self.root.push(gj::Node {
            mesh: Some(mesh),
            skin: Some(skin),
            name: Some(name.to_string()),
            ..Default::default()
        });
        debug_assert_eq!(node.value() as u32, MESH_NODE);
        let scene = self.root.push(gj::Scene {
            extensions: Default::default(),
            extras: Default::default(),
            name: Some(name.to_string()),
            nodes: vec![Index::new(0), node],
        });
        self.root.scene = Some(scene);
    }

    fn animation(&mut self, keys: &Keyframes) {
        use gj::accessor::Type;
        use gj::animation::{Channel, Interpolation, Property, Sampler, Target};
        let times: Vec<[f32; 1]> = keys.times.iter().map(|&t| [t]).collect();
        let input = self.floats(&times, Type::Scalar, None, true);
        let mut outputs = Vec::new();
        for (j, rotations) in keys.rotations.iter().enumerate() {
            let values: Vec<[f32; 4]> = rotations.iter().map(|q| q.to_array()).collect();
            let output = self.floats(&values, Type::Vec4, None, false);
            outputs.push((j, Property::Rotation, output));
        }
        let moves: Vec<[f32; 3]> = keys.root_translation.iter().map(Vec3::to_array).collect();
        let output = self.floats(&moves, Type::Vec3, None, false);
        outputs.push((0, Property::Translation, output));
        let samplers = outputs
            .iter()
            .map(|&(_, _, output)| Sampler {
                input,
                interpolation: Valid(Interpolation::Linear),
                output,
                extensions: Default::default(),
                extras: Default::default(),
            })
            .collect();
        let channels = outputs
            .into_iter()
            .enumerate()
            .map(|(k, (node, path, _))| Channel {
                sampler: Index::new(k as u32),
                target: Target {
                    node: Index::new(node as u32),
                    path: Valid(path),
                    extensions: Default::default(),
                    extras: Default::default(),
                },
                extensions: Default::default(),
                extras: Default::default(),
            })
            .collect();
        self.root.push(gj::Animation {
            extensions: Default::default(),
            extras: Default::default(),
            channels,
            name: Some("motion".into()),
            samplers,
        });
    }

    fn finish(mut self) -> Result<Vec<u8>, ExportError> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.root.asset = gj::Asset {
            generator: Some(format!("talkin export {}", env!("CARGO_PKG_VERSION"))),
            version: "2.0".into(),
            ..Default::default()
        };
        self.root.buffers = vec![gj::Buffer {
            byte_length: USize64::from(self.bin.len()),
            name: None,
            uri: None,
            extensions: Default::default(),
            extras: Default::default(),
        }];
        let json = self
            .root
            .to_vec()
            .map_err(|e| ExportError::Gltf(e.to_string()))?;
        gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length: 0,
            },
            json: Cow::Owned(json),
            bin: Some(Cow::Owned(self.bin)),
        }
        .to_vec()
        .map_err(|e| ExportError::Gltf(e.to_string()))
    }
}
