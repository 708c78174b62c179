//! The Sweet Home 3D furniture catalog: every `*.sh3f` archive in the furniture folder is a
//! zip with OBJ/MTL models and a `PluginFurnitureCatalog.properties` (Java properties,
//! ISO-8859-1 with `\uXXXX` escapes) listing each model's id, name, category, size in cm,
//! creator and the library's license. This module reads those lists, maps names to plain
//! English labels (or drops the model: doors, outdoor things, clothes, tiny props), marks the
//! models reserved for evaluation (`trainer/eval-reserved-meshes.txt`, compiled in) and keeps
//! each model's credit. Catalogs are parsed once per process and folder.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use glam::{Mat3, Vec3};

use super::SynthError;

/// Models kept out of training: lines `Library name#id`.
const RESERVED: &str = include_str!("../eval-reserved-meshes.txt");

/// Who made a model and under which license.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub struct Credit {
    /// Catalog id, `Library name#id`.
    pub id: String,
    pub name: String,
    pub creator: String,
    pub license: String,
}

/// One usable furniture model.
#[derive(Debug, Clone, PartialEq)]
pub struct CatalogEntry {
    pub credit: Credit,
    /// Plain English label (`chair`, `bookcase`, ...).
    pub label: &'static str,
    /// Width (x), height (y), depth (z) in metres.
    pub size: Vec3,
    /// Height of the surface other things may stand on, metres.
    pub top: Option<f32>,
    pub archive: PathBuf,
    /// Path of the OBJ inside the archive (no leading slash).
    pub model: String,
    pub rotation: Option<Mat3>,
    /// Listed in eval-reserved-meshes.txt: never used for train/val.
    pub reserved: bool,
}

/// All usable models of one furniture folder, sorted by id.
#[derive(Debug)]
pub struct Catalog {
    pub dir: PathBuf,
    pub entries: Vec<CatalogEntry>,
}

impl Catalog {
    /// The catalog of `dir`, parsed once per process.
    pub fn open(dir: &Path) -> Result<Arc<Catalog>, SynthError> {
        static CACHE: OnceLock<Mutex<BTreeMap<PathBuf, Arc<Catalog>>>> = OnceLock::new();
        let cache = CACHE.get_or_init(Default::default);
        if let Some(c) = cache.lock().expect("catalog cache poisoned").get(dir) {
            return Ok(c.clone());
        }
        let catalog = Arc::new(Self::read(dir)?);
        cache.lock().expect("catalog cache poisoned").insert(dir.to_path_buf(), catalog.clone());
        Ok(catalog)
    }

    fn read(dir: &Path) -> Result<Catalog, SynthError> {
        let bad_dir =
            |problem: String| SynthError::FurnitureDir { dir: dir.to_path_buf(), problem };
        let listing = std::fs::read_dir(dir).map_err(|e| bad_dir(e.to_string()))?;
        let mut archives: Vec<PathBuf> = listing
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "sh3f"))
            .collect();
        archives.sort();
        if archives.is_empty() {
            return Err(bad_dir(
                "no *.sh3f furniture libraries in it (install sweethome3d-furniture)".into(),
            ));
        }
        let reserved: BTreeSet<&str> = RESERVED
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .collect();
        let mut entries = Vec::new();
        for archive in &archives {
            let text = read_properties(archive)?;
            entries.extend(parse_catalog(&text, archive, &reserved));
        }
        entries.sort_by(|a, b| a.credit.id.cmp(&b.credit.id));
        entries.dedup_by(|a, b| a.credit.id == b.credit.id);
        Ok(Catalog { dir: dir.to_path_buf(), entries })
    }

    /// Labels that have at least one model allowed by `reserved`.
    pub fn labels(&self, reserved: super::Reserved) -> BTreeSet<&'static str> {
        self.entries.iter().filter(|e| reserved.allows(e.reserved)).map(|e| e.label).collect()
    }
}

fn read_properties(archive: &Path) -> Result<String, SynthError> {
    let err = |problem: String| SynthError::Archive {
        archive: archive.to_path_buf(),
        entry: "PluginFurnitureCatalog.properties".into(),
        problem,
    };
    let file = std::fs::File::open(archive).map_err(|e| err(e.to_string()))?;
    let mut zip =
        zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| err(e.to_string()))?;
    let mut entry =
        zip.by_name("PluginFurnitureCatalog.properties").map_err(|e| err(e.to_string()))?;
    let mut bytes = Vec::new();
    entry.read_to_end(&mut bytes).map_err(|e| err(e.to_string()))?;
    // ISO-8859-1: every byte is the code point of the same value.
    Ok(bytes.iter().map(|&b| char::from(b)).collect())
}

/// Java properties → key/value pairs (comments, continuations and `\uXXXX` escapes handled).
fn parse_properties(text: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut logical = String::new();
    for line in text.lines() {
        let line = if logical.is_empty() { line.trim_start() } else { line.trim() };
        if logical.is_empty() && (line.starts_with('#') || line.starts_with('!') || line.is_empty())
        {
            continue;
        }
        if let Some(stripped) = line.strip_suffix('\\').filter(|s| !s.ends_with('\\')) {
            logical.push_str(stripped);
            continue;
        }
        logical.push_str(line);
        if let Some(eq) = logical.find('=') {
            out.push((unescape(logical[..eq].trim()), unescape(logical[eq + 1..].trim())));
        }
        logical.clear();
    }
    out
}

fn unescape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match chars.next() {
            Some('u') => {
                let hex: String = chars.by_ref().take(4).collect();
                out.extend(u32::from_str_radix(&hex, 16).ok().and_then(char::from_u32));
            }
            Some('n') => out.push('\n'),
            Some('t') => out.push('\t'),
            Some(other) => out.push(other),
            None => {}
        }
    }
    out
}

fn parse_catalog(text: &str, archive: &Path, reserved: &BTreeSet<&str>) -> Vec<CatalogEntry> {
    let mut license = String::new();
    let mut items: BTreeMap<u32, BTreeMap<String, String>> = BTreeMap::new();
    for (key, value) in parse_properties(text) {
        match key.split_once('#') {
            Some((field, n)) => {
                if let Ok(n) = n.parse() {
                    items.entry(n).or_default().insert(field.to_string(), value);
                }
            }
            None if key == "license" => license = value,
            None => {}
        }
    }
    items.values().filter_map(|f| entry_from_fields(f, &license, archive, reserved)).collect()
}

fn entry_from_fields(
    f: &BTreeMap<String, String>,
    license: &str,
    archive: &Path,
    reserved: &BTreeSet<&str>,
) -> Option<CatalogEntry> {
    let get = |k: &str| f.get(k).map(String::as_str);
    let num = |k: &str| get(k).and_then(|v| v.trim().parse::<f32>().ok());
    if get("doorOrWindow") == Some("true") || num("elevation").is_some_and(|e| e > 0.0) {
        return None;
    }
    if matches!(
        get("category")?,
        "Exterior"
            | "Doors and windows"
            | "Characters"
            | "Vehicles"
            | "Staircases"
            | "Miscellaneous exterior"
    ) {
        return None;
    }
    let name = get("name")?;
    let label = label_for(name)?;
    let size = Vec3::new(num("width")?, num("height")?, num("depth")?) / 100.0;
    let small_ok =
        matches!(label, "lamp" | "vase" | "plant" | "tv" | "speaker" | "computer" | "fan" | "box");
    if size.min_element() <= 0.0
        || size.max_element() > 3.0
        || (size.y < 0.3 && !small_ok)
        || size.y < 0.15
    {
        return None;
    }
    let supports = matches!(
        label,
        "table"
            | "coffee table"
            | "desk"
            | "nightstand"
            | "cabinet"
            | "dresser"
            | "tv stand"
            | "bookcase"
    );
    let top =
        supports.then(|| num("dropOnTopElevation").map_or(size.y, |cm| (cm / 100.0).min(size.y)));
    let rotation = get("modelRotation").and_then(|r| {
        let v: Vec<f32> = r.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        // Row-major in the catalog; glam takes columns.
        (v.len() == 9)
            .then(|| Mat3::from_cols_array(&[v[0], v[3], v[6], v[1], v[4], v[7], v[2], v[5], v[8]]))
    });
    let id = get("id")?.to_string();
    Some(CatalogEntry {
        reserved: reserved.contains(id.as_str()),
        credit: Credit {
            id,
            name: name.to_string(),
            creator: get("creator").unwrap_or("unknown").to_string(),
            license: license.to_string(),
        },
        label,
        size,
        top,
        archive: archive.to_path_buf(),
        model: get("model")?.trim_start_matches('/').to_string(),
        rotation,
    })
}

/// Label rules, first match wins: (label, phrases). A phrase matches whole words.
const RULES: &[(&str, &[&str])] = &[
    ("office chair", &["office chair", "desk chair", "swivel chair"]),
    ("armchair", &["armchair", "fotel", "easy chair", "club chair", "ryokan chair"]),
    ("stool", &["stool", "pouf", "puff", "ottoman"]),
    ("sofa", &["sofa", "couch", "settee", "loveseat"]),
    ("nightstand", &["bedside", "nightstand", "night table"]),
    ("coffee table", &["coffee table", "low table", "side table"]),
    ("lamp", &["lamp", "lantern", "chandelier", "lampshade"]),
    ("tv stand", &["tv stand", "television cabinet", "tv cabinet", "tv unit"]),
    ("tv", &["tv", "television"]),
    ("bed", &["bed", "crib", "futon", "cot"]),
    ("bench", &["bench"]),
    ("chair", &["chair"]),
    ("desk", &["desk"]),
    ("pool table", &["pool table", "billiard"]),
    ("fan", &["fan"]),
    ("table", &["table"]),
    ("bookcase", &["bookcase", "bookshelf", "shelves", "shelf", "shelving"]),
    ("wardrobe", &["wardrobe", "closet", "armoire"]),
    ("dresser", &["dresser", "drawers", "commode", "chest"]),
    ("cabinet", &["cabinet", "cupboard", "sideboard", "buffet", "locker"]),
    (
        "plant",
        &[
            "plant",
            "ficus",
            "yucca",
            "bamboo",
            "bonsai",
            "tulips",
            "orchids",
            "lily",
            "flowers",
            "spathiphyllum",
            "cactus",
            "palm",
            "fern",
            "christmas tree",
        ],
    ),
    ("piano", &["piano"]),
    ("refrigerator", &["fridge", "refrigerator", "freezer"]),
    ("washing machine", &["washing machine", "dryer machine", "washer"]),
    ("oven", &["oven", "stove", "cooker"]),
    ("sink", &["sink", "washbasin", "vanity"]),
    ("toilet", &["toilet", "toilets"]),
    ("bathtub", &["bath", "bathtub"]),
    ("speaker", &["speaker", "loudspeaker"]),
    ("trash can", &["dustbin", "trash", "bin", "garbage", "wastebasket"]),
    ("vase", &["vase"]),
    ("radiator", &["radiator"]),
    ("fireplace", &["fireplace", "chimney"]),
    ("computer", &["computer", "imac", "laptop"]),
    ("guitar", &["guitar"]),
    ("box", &["box", "crate", "trunk", "trunck"]),
];

/// Every label a catalog model can get.
pub fn rule_labels() -> impl Iterator<Item = &'static str> {
    RULES.iter().map(|(label, _)| *label)
}

/// Words that disqualify a model whatever else its name says (accessories, outdoor or wall
/// items, things that are not furniture).
const EXCLUDE: &[&str] = &[
    "brush",
    "paper",
    "holder",
    "dispenser",
    "remote",
    "joystick",
    "hood",
    "switch",
    "plug",
    "railing",
    "wheelchair",
    "street",
    "park",
    "football",
    "tennis",
    "ceiling",
    "wall",
    "mattress",
    "sleeping",
    "doll",
    "curtain",
    "door",
    "shower",
    "tools",
    "cooktop",
    "pallet",
    "kitchen",
    "island",
    "lamppost",
    "fence",
    "child",
    "children",
    "baby",
    "high",
];

/// The plain English label of a catalog model name, or `None` when it is not furniture this
/// synthesizer places.
pub fn label_for(name: &str) -> Option<&'static str> {
    let lower = name.to_lowercase();
    let words: Vec<&str> =
        lower.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).collect();
    if words.iter().any(|w| EXCLUDE.contains(w)) {
        return None;
    }
    let has = |phrase: &str| {
        let p: Vec<&str> = phrase.split(' ').collect();
        words.windows(p.len()).any(|w| w == p.as_slice())
    };
    RULES.iter().find(|(_, phrases)| phrases.iter().any(|p| has(p))).map(|(label, _)| *label)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_to_plain_labels() {
        for (name, label) in [
            ("Desk lamp", Some("lamp")),
            ("Bedside table", Some("nightstand")),
            ("Coffee table", Some("coffee table")),
            ("Oak chair", Some("chair")),
            ("Office chair", Some("office chair")),
            ("Corner sofa", Some("sofa")),
            ("Television cabinet", Some("tv stand")),
            ("TV 16:9", Some("tv")),
            ("Kitchen cabinet", None),
            ("Toilet brush", None),
            ("Table fan", Some("fan")),
            ("Lower cabinet", Some("cabinet")),
            ("Dresser with drawers", Some("dresser")),
            ("Spider plant", Some("plant")),
            ("Scissors", None),
        ] {
            assert_eq!(label_for(name), label, "{name}");
        }
    }

    #[test]
    fn properties_parse_escapes_and_entries() {
        let text = "# comment\nlicense=CC-BY\nid#1=Lib#chair\nname#1=Chair \\u00e9\ncategory#1=Living room\n\
                    model#1=/lib/chair/chair.obj\nwidth#1=50\ndepth#1=55\nheight#1=90\ncreator#1=Someone\n\
                    dropOnTopElevation#1=45\nid#2=Lib#door\nname#2=Door\ncategory#2=Doors and windows\n\
                    model#2=/d.obj\nwidth#2=90\ndepth#2=10\nheight#2=200\ndoorOrWindow#2=true\n";
        let reserved: BTreeSet<&str> = ["Lib#chair"].into();
        let e = parse_catalog(text, Path::new("x.sh3f"), &reserved);
        assert_eq!(e.len(), 1);
        assert_eq!(e[0].credit.name, "Chair é");
        assert_eq!(e[0].credit.license, "CC-BY");
        assert_eq!(e[0].label, "chair");
        assert_eq!(e[0].model, "lib/chair/chair.obj");
        assert!(e[0].reserved);
        assert!((e[0].size - Vec3::new(0.5, 0.9, 0.55)).length() < 1e-6);
    }

    #[test]
    fn reserved_list_is_compiled_in() {
        assert!(RESERVED.lines().any(|l| l == "Blend Swap CC-0#bed2"));
    }
}
