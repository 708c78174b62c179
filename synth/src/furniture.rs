//! Loading catalog furniture into ray-castable meshes: the OBJ, its MTL and its textures are
//! read straight out of the `.sh3f` zip with `tobj`, rotated by the catalog's model rotation,
//! scaled to the catalog size (cm → m, base on the floor, centred), decimated to
//! [`TRIANGLE_BUDGET`] triangles by vertex clustering, and textures are shrunk to at most
//! [`TEXTURE_SIZE`] texels a side. Models above [`MAX_SOURCE_TRIANGLES`] are skipped (trees
//! and the like: slow to parse, useless at 128 px). Every result — mesh or error — is cached
//! per process, so a model is parsed once however many scenes and threads use it.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::io::{Cursor, Read};
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock};

use glam::{Vec2, Vec3};

use super::SynthError;
use super::catalog::CatalogEntry;
use super::mesh::{Material, Mesh, MeshBuilder, Texture};
use super::texture::srgb_to_linear;

/// Triangles kept per catalog model after decimation.
pub const TRIANGLE_BUDGET: usize = 6000;
/// Models with more source triangles than this are not used.
pub const MAX_SOURCE_TRIANGLES: usize = 250_000;
/// Largest texture side kept, in texels.
pub const TEXTURE_SIZE: u32 = 64;

type Cell = Arc<OnceLock<Result<Arc<Mesh>, String>>>;

/// The mesh of a catalog model, loaded once per process.
pub fn load(entry: &CatalogEntry) -> Result<Arc<Mesh>, SynthError> {
    static CACHE: OnceLock<Mutex<BTreeMap<String, Cell>>> = OnceLock::new();
    let key = format!("{}|{}", entry.archive.display(), entry.credit.id);
    let cell: Cell = CACHE
        .get_or_init(Default::default)
        .lock()
        .expect("mesh cache poisoned")
        .entry(key)
        .or_default()
        .clone();
    cell.get_or_init(|| read_model(entry).map(Arc::new)).clone().map_err(|problem| {
        SynthError::Archive { archive: entry.archive.clone(), entry: entry.model.clone(), problem }
    })
}

fn read_model(entry: &CatalogEntry) -> Result<Mesh, String> {
    let file = std::fs::File::open(&entry.archive).map_err(|e| e.to_string())?;
    let zip = RefCell::new(
        zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| e.to_string())?,
    );
    let read = |name: &str| -> Result<Vec<u8>, String> {
        let mut zip = zip.borrow_mut();
        let mut f = zip.by_name(name).map_err(|e| format!("{name}: {e}"))?;
        let mut bytes = Vec::new();
        f.read_to_end(&mut bytes).map_err(|e| format!("{name}: {e}"))?;
        Ok(bytes)
    };
    let dir = Path::new(&entry.model)
        .parent()
        .map(|p| p.to_string_lossy().into_owned())
        .unwrap_or_default();
    let join = |rel: &str| -> String {
        let rel = rel.trim().replace('\\', "/");
        if dir.is_empty() { rel } else { format!("{dir}/{rel}") }
    };
    let obj = read(&entry.model)?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, materials) = tobj::load_obj_buf(&mut Cursor::new(obj), &options, |p| {
        let bytes =
            read(&join(&p.to_string_lossy())).map_err(|_| tobj::LoadError::OpenFileFailed)?;
        tobj::load_mtl_buf(&mut Cursor::new(bytes))
    })
    .map_err(|e| format!("OBJ: {e}"))?;
    let materials = materials.unwrap_or_default();
    let source: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    if source > MAX_SOURCE_TRIANGLES {
        return Err(format!(
            "{source} triangles, above the {MAX_SOURCE_TRIANGLES} this synthesizer loads"
        ));
    }

    let mut b = MeshBuilder::default();
    let mut textures: BTreeMap<String, Option<Arc<Texture>>> = BTreeMap::new();
    let mut slots: BTreeMap<Option<usize>, Option<u16>> = BTreeMap::new();
    for model in &models {
        let m = &model.mesh;
        let slot = *slots.entry(m.material_id).or_insert_with(|| {
            let mat = m.material_id.and_then(|i| materials.get(i));
            if mat.and_then(|x| x.dissolve).is_some_and(|d| d < 0.3) {
                return None; // glass: see-through, left out
            }
            let albedo = mat
                .and_then(|x| x.diffuse)
                .map_or(Vec3::splat(0.6), |d| srgb_to_linear(Vec3::from(d)));
            let texture = mat.and_then(|x| x.diffuse_texture.as_deref()).and_then(|t| {
                let name = join(t);
                textures
                    .entry(name.clone())
                    .or_insert_with(|| read(&name).ok().and_then(|b| decode_texture(&b)))
                    .clone()
            });
            Some(b.material(Material { albedo, texture, pattern: None }))
        });
        let Some(material) = slot else { continue };
        let pos = |i: u32| {
            Vec3::new(
                m.positions[3 * i as usize],
                m.positions[3 * i as usize + 1],
                m.positions[3 * i as usize + 2],
            )
        };
        let uv = |i: u32| {
            let i = i as usize;
            if m.texcoords.len() >= 2 * i + 2 {
                Vec2::new(m.texcoords[2 * i], m.texcoords[2 * i + 1])
            } else {
                Vec2::ZERO
            }
        };
        for c in m.indices.chunks_exact(3) {
            b.triangle([pos(c[0]), pos(c[1]), pos(c[2])], [uv(c[0]), uv(c[1]), uv(c[2])], material);
        }
    }
    if b.triangle_count() == 0 {
        return Err("no triangles".into());
    }
    if let Some(r) = entry.rotation {
        b.transform(r);
    }
    b.decimate(TRIANGLE_BUDGET);
    b.fit_to(entry.size);
    Ok(b.build())
}

fn decode_texture(bytes: &[u8]) -> Option<Arc<Texture>> {
    let img = image::load_from_memory(bytes).ok()?;
    let small = img.thumbnail(TEXTURE_SIZE, TEXTURE_SIZE).into_rgb8();
    let texels = small
        .pixels()
        .map(|p| srgb_to_linear(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 255.0))
        .collect();
    Some(Arc::new(Texture { width: small.width(), height: small.height(), texels }))
}

/// A furniture model ready to place: its mesh, label, credit (catalog models) and the height
/// of the surface small things may stand on.
#[derive(Debug, Clone)]
pub struct Model {
    pub mesh: Arc<Mesh>,
    pub label: &'static str,
    pub credit: Option<super::catalog::Credit>,
    pub top: Option<f32>,
}

impl Model {
    pub fn from_entry(entry: &CatalogEntry) -> Result<Model, SynthError> {
        Ok(Model {
            mesh: load(entry)?,
            label: entry.label,
            credit: Some(entry.credit.clone()),
            top: entry.top,
        })
    }
}
