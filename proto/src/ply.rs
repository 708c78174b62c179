//! 3DGS PLY files: binary little-endian `vertex` elements with the standard INRIA properties
//! first (`x y z nx ny nz f_dc_0..2 opacity scale_0..2 rot_0..3`), then inssplat's extras
//! (`confidence`, `instance_id`, `ins_0..7`, `sem_0..`), metadata in `comment` lines.
//!
//! The header is written and parsed by `ply-rs-bw`; the payload is read through it as well
//! (so ASCII and big-endian files from other tools load too) and written directly as packed
//! little-endian scalars. Reading tolerates missing extras and ignores unknown properties
//! (`f_rest_*`: inssplat keeps SH degree 0). A truncated binary payload is reported with the
//! element, the record index and the property where the data ends.

use std::io::{Cursor, Read, Write};

use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Header, Property, PropertyAccess, PropertyAccessResult,
    PropertyDef, PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use crate::gaussian::{GaussianScene, INSTANCE_DIM, LengthMismatch, SceneMeta};

/// The standard 3DGS vertex properties, in order.
pub const STANDARD_PROPERTIES: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Properties a reader cannot do without.
const REQUIRED: [&str; 14] = [
    "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
    "rot_0", "rot_1", "rot_2", "rot_3",
];

#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    #[error("malformed PLY header: {0}")]
    Header(String),
    #[error("PLY has no `{0}` element")]
    MissingElement(&'static str),
    #[error("element `{element}` lacks required property `{property}`")]
    MissingProperty { element: String, property: &'static str },
    #[error("element `{element}` property `{property}` has type {found}, expected a scalar number")]
    BadType { element: String, property: String, found: String },
    #[error(
        "truncated PLY: element `{element}` record {index} of {count} ends inside property `{property}`"
    )]
    Truncated { element: String, index: usize, count: usize, property: String },
    #[error("malformed PLY payload in element `{element}`: {message}")]
    Payload { element: String, message: String },
    #[error("invalid scene: {0}")]
    Invalid(#[from] LengthMismatch),
}

/// Writes `scene` as a binary little-endian 3DGS PLY.
pub fn write_ply<W: Write>(out: &mut W, scene: &GaussianScene) -> Result<(), PlyError> {
    scene.validate()?;
    let mut header = Header::new();
    header.encoding = Encoding::BinaryLittleEndian;
    header.comments = meta_comments(&scene.meta, scene.sem_dim);
    let mut vertex = ElementDef::new("vertex".to_string());
    vertex.count = scene.len();
    let float = PropertyType::Scalar(ScalarType::Float);
    for name in STANDARD_PROPERTIES {
        vertex.properties.add(PropertyDef::new(name.to_string(), float.clone()));
    }
    vertex.properties.add(PropertyDef::new("confidence".into(), float.clone()));
    vertex
        .properties
        .add(PropertyDef::new("instance_id".into(), PropertyType::Scalar(ScalarType::UInt)));
    for i in 0..INSTANCE_DIM {
        vertex.properties.add(PropertyDef::new(format!("ins_{i}"), float.clone()));
    }
    for i in 0..scene.sem_dim {
        vertex.properties.add(PropertyDef::new(format!("sem_{i}"), float.clone()));
    }
    header.elements.add(vertex);
    Writer::<ply_rs_bw::ply::DefaultElement>::new()
        .write_header(out, &header)
        .map_err(|e| PlyError::Header(e.to_string()))?;

    let record = 4 * (STANDARD_PROPERTIES.len() + 2 + INSTANCE_DIM + scene.sem_dim);
    let mut buf = Vec::with_capacity(record * scene.len());
    for i in 0..scene.len() {
        let mut f = |v: f32| buf.extend_from_slice(&v.to_le_bytes());
        scene.means[i].iter().for_each(|&v| f(v));
        [0.0; 3].iter().for_each(|&v| f(v));
        scene.sh_dc[i].iter().for_each(|&v| f(v));
        f(scene.logit_opacity[i]);
        scene.log_scales[i].iter().for_each(|&v| f(v));
        scene.rotations[i].iter().for_each(|&v| f(v));
        f(scene.confidence[i]);
        buf.extend_from_slice(&scene.instance_id[i].to_le_bytes());
        scene.instance_embedding[i].iter().for_each(|&v| buf.extend_from_slice(&v.to_le_bytes()));
        scene.semantic_of(i).iter().for_each(|&v| buf.extend_from_slice(&v.to_le_bytes()));
    }
    out.write_all(&buf)?;
    Ok(())
}

fn meta_comments(meta: &SceneMeta, sem_dim: usize) -> Vec<String> {
    let mut c = vec![format!(
        "producer {}",
        if meta.producer.is_empty() { "inssplat" } else { &meta.producer }
    )];
    if let Some(v) = &meta.model_version {
        c.push(format!("model_version {v}"));
    }
    if let Some(up) = &meta.up_axis {
        c.push(format!("up_axis {up}"));
    }
    c.push(format!("sem_dim {sem_dim}"));
    for (id, label) in &meta.labels {
        c.push(format!("label {id} {}", label.replace('\n', " ")));
    }
    c
}

fn parse_meta(comments: &[String]) -> SceneMeta {
    let mut meta = SceneMeta::default();
    for line in comments {
        let (key, rest) = line.split_once(' ').unwrap_or((line.as_str(), ""));
        match key {
            "producer" => meta.producer = rest.to_string(),
            "model_version" => meta.model_version = Some(rest.to_string()),
            "up_axis" => meta.up_axis = Some(rest.to_string()),
            "label" => {
                if let Some((id, text)) = rest.split_once(' ')
                    && let Ok(id) = id.parse()
                {
                    meta.labels.push((id, text.to_string()));
                }
            }
            _ => {}
        }
    }
    meta
}

/// Reads a 3DGS PLY: inssplat's own, or one written by another tool (no extras).
pub fn read_ply<R: Read>(input: &mut R) -> Result<GaussianScene, PlyError> {
    let mut bytes = Vec::new();
    input.read_to_end(&mut bytes)?;
    let mut reader = Reader::new(Cursor::new(bytes.as_slice()));
    let parser = Parser::<VertexRecord>::new();
    let header = parser.read_header(&mut reader).map_err(|e| PlyError::Header(e.to_string()))?;
    let Some(vertex) = header.elements.get("vertex") else {
        return Err(PlyError::MissingElement("vertex"));
    };
    for name in REQUIRED {
        match vertex.properties.get(name) {
            None => {
                return Err(PlyError::MissingProperty { element: "vertex".into(), property: name });
            }
            Some(p) if !matches!(p.data_type, PropertyType::Scalar(_)) => {
                return Err(PlyError::BadType {
                    element: "vertex".into(),
                    property: name.into(),
                    found: format!("{:?}", p.data_type),
                });
            }
            Some(_) => {}
        }
    }
    let payload_start = reader.get_ref().position() as usize;
    check_binary_length(&header, bytes.len() - payload_start)?;

    let sem_dim = (0..).take_while(|i| vertex.properties.contains_key(&format!("sem_{i}"))).count();
    let mut scene = GaussianScene::with_sem_dim(sem_dim);
    scene.meta = parse_meta(&header.comments);
    for (name, element) in &header.elements {
        let records = parser
            .read_payload_for_element(&mut reader, element, &header)
            .map_err(|e| PlyError::Payload { element: name.clone(), message: e.to_string() })?;
        if name != "vertex" {
            continue;
        }
        scene_from_records(&mut scene, records, sem_dim);
    }
    Ok(scene)
}

fn scene_from_records(scene: &mut GaussianScene, records: Vec<VertexRecord>, sem_dim: usize) {
    scene.reserve(records.len());
    for mut r in records {
        r.sem.resize(sem_dim, 0.0);
        scene.push(crate::gaussian::Gaussian {
            mean: r.mean,
            log_scale: r.scale,
            rotation: r.rot,
            logit_opacity: r.opacity,
            sh_dc: r.dc,
            confidence: r.confidence.unwrap_or(1.0),
            instance_embedding: r.ins,
            semantic: &r.sem,
            instance_id: r.instance_id,
        });
    }
}

/// For binary payloads of scalar-only elements, checks the byte count up front so a
/// truncated file names the record and property where it ends.
fn check_binary_length(header: &Header, available: usize) -> Result<(), PlyError> {
    if header.encoding == Encoding::Ascii {
        return Ok(());
    }
    let mut offset = 0usize;
    for (name, element) in &header.elements {
        let sizes: Option<Vec<usize>> = element
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(s) => Some(scalar_size(s)),
                PropertyType::List(..) => None,
            })
            .collect();
        let Some(sizes) = sizes else { return Ok(()) };
        let record: usize = sizes.iter().sum();
        let need = record * element.count;
        let have = available.saturating_sub(offset);
        if have < need {
            let index = have / record.max(1);
            let mut within = have % record.max(1);
            let mut property = String::new();
            for (p, size) in element.properties.values().zip(&sizes) {
                property = p.name.clone();
                if within < *size {
                    break;
                }
                within -= size;
            }
            return Err(PlyError::Truncated {
                element: name.clone(),
                index,
                count: element.count,
                property,
            });
        }
        offset += need;
    }
    Ok(())
}

fn scalar_size(s: &ScalarType) -> usize {
    match s {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// One vertex as the parser fills it.
struct VertexRecord {
    mean: [f32; 3],
    dc: [f32; 3],
    opacity: f32,
    scale: [f32; 3],
    rot: [f32; 4],
    confidence: Option<f32>,
    instance_id: u32,
    ins: [f32; INSTANCE_DIM],
    sem: Vec<f32>,
}

impl VertexRecord {
    fn set(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        let slot = match name {
            "x" => &mut self.mean[0],
            "y" => &mut self.mean[1],
            "z" => &mut self.mean[2],
            "f_dc_0" => &mut self.dc[0],
            "f_dc_1" => &mut self.dc[1],
            "f_dc_2" => &mut self.dc[2],
            "opacity" => &mut self.opacity,
            "scale_0" => &mut self.scale[0],
            "scale_1" => &mut self.scale[1],
            "scale_2" => &mut self.scale[2],
            "rot_0" => &mut self.rot[0],
            "rot_1" => &mut self.rot[1],
            "rot_2" => &mut self.rot[2],
            "rot_3" => &mut self.rot[3],
            "confidence" => {
                self.confidence = Some(v);
                return PropertyAccessResult::Set;
            }
            "instance_id" => {
                self.instance_id = v as u32;
                return PropertyAccessResult::Set;
            }
            _ => return self.set_indexed(name, v),
        };
        *slot = v;
        PropertyAccessResult::Set
    }

    fn set_indexed(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        if let Some(i) = name.strip_prefix("ins_").and_then(|i| i.parse::<usize>().ok())
            && i < INSTANCE_DIM
        {
            self.ins[i] = v;
        } else if let Some(i) = name.strip_prefix("sem_").and_then(|i| i.parse::<usize>().ok()) {
            if self.sem.len() <= i {
                self.sem.resize(i + 1, 0.0);
            }
            self.sem[i] = v;
        } else {
            return PropertyAccessResult::Ignored;
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for VertexRecord {
    fn new() -> Self {
        Self {
            mean: [0.0; 3],
            dc: [0.0; 3],
            opacity: 0.0,
            scale: [0.0; 3],
            rot: [1.0, 0.0, 0.0, 0.0],
            confidence: None,
            instance_id: 0,
            ins: [0.0; INSTANCE_DIM],
            sem: Vec::new(),
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        match property.to_f32_lossy() {
            Some(v) => self.set(name, v),
            None => PropertyAccessResult::Ignored,
        }
    }

    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set(name, v)
    }

    fn set_uint(&mut self, name: &str, v: u32) -> PropertyAccessResult {
        if name == "instance_id" {
            self.instance_id = v;
            PropertyAccessResult::Set
        } else {
            self.set(name, v as f32)
        }
    }
}

#[cfg(test)]
mod tests;
