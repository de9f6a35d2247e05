//! The map file: the whole state a later session needs to go on in a map — localise in it
//! (`dwslam run --load-map FILE --localise`) or map on from it — written by
//! `dwslam run --save-map FILE` (format: `docs/map-format.md`).
//!
//! What it holds: the SLAM graph (every keyframe's pose, map, measurements and edges, every
//! point's anchor and inverse depth, the maps, their merges and joins, ids and versions:
//! `slam::map::GraphParts`), each keyframe's place-recognition features (ORB keypoints,
//! descriptors and their 3D points or depth samples; the words are the vocabulary's transform
//! of the descriptors, recomputed on load in a fraction of a millisecond), each keyframe's
//! image where the guided search needs it (the neighbourhood of the points it anchors, whose
//! templates are warped from there: [`crate::search`]; the rest is not stored), the camera,
//! the vocabulary's identity and the configuration.
//!
//! The file: a fixed header — magic `DWSLAMAP`, format version, flags, body length, CRC-32 of
//! the body — then the body in postcard (serde's compact binary format with a written,
//! frozen wire specification: varints, no field names, no padding). Chosen on evidence: the
//! body is mostly descriptors, pixels and doubles, which a self-describing format (CBOR,
//! MessagePack) would only tag; a 7-Scenes map is written and read in milliseconds; schema
//! evolution is the header's version — a reader knows every version it reads and refuses a
//! newer one by name — rather than optional fields a non-self-describing format cannot skip.
//! Written atomically (a temporary file beside the target, synced, renamed), read with every
//! part checked — the checksum, then the decoding, then the graph's invariants — so that a
//! truncated, corrupted or mismatched map is a clear error naming the file, never a panic.

use crate::keyframes::{KeyframeImages, KeyframeStore};
use crate::place_recognition::KeyframeFeatures;
use crate::run_graph::RunGraph;
use data::camera::{SensorKind, SensorModel};
use geom::PinholeCamera;
use lie::{Sim3, So3};
use nalgebra::{Quaternion, SVector, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use slam::map::{
    Edge, GraphParts, KeyframeId, KeyframePart, MapJoin, MapMerge, PointId, PointPart, SlamGraph,
};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use vision::bow::Vocabulary;
use vision::image::GrayImage;
use vision::orb::KeyPoint;

/// The first bytes of every map file.
pub const MAGIC: [u8; 8] = *b"DWSLAMAP";

/// The format version this build writes (and the newest it reads).
pub const FORMAT_VERSION: u32 = 1;

/// Magic, version, flags, body length, CRC-32.
const HEADER_LEN: usize = 8 + 4 + 4 + 8 + 4;

/// Side of the image blocks a map file keeps (pixels).
const BLOCK: usize = 8;

/// A keyframe's image is kept within this many pixels of each point it anchors: the guided
/// search warps an 8×8 template (plus a pixel for its gradient, 5 px from the point) from
/// there, over a footprint that grows with the ratio of the point's depths — 12 px covers a
/// view up to 2.4 times farther away than the anchor's. Measured (2026-12-05): localising
/// 7-Scenes in maps of its first half gave the same trajectories bit for bit with 12 px as
/// with whole images; 8 px did not (4.06 → 5.36 cm).
const TEMPLATE_REACH_PX: f64 = 12.0;

/// Why a map file could not be read, written or used.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    /// The file could not be read.
    #[error("cannot read map {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("cannot write map {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// No map header.
    #[error("{path} is not a dwslam map (it does not start with DWSLAMAP)")]
    NotAMap {
        /// The file.
        path: PathBuf,
    },
    /// Shorter (or longer) than its header says.
    #[error(
        "map {path} is truncated or has trailing bytes: {expected} bytes expected, {found} found"
    )]
    Truncated {
        /// The file.
        path: PathBuf,
        /// The length the header gives.
        expected: u64,
        /// The file's length.
        found: u64,
    },
    /// The body's checksum does not match.
    #[error(
        "map {path} is corrupted: the checksum of its contents does not match (CRC-32 {stored:08x} stored, {computed:08x} computed)"
    )]
    Corrupted {
        /// The file.
        path: PathBuf,
        /// The checksum in the header.
        stored: u32,
        /// The checksum of the body.
        computed: u32,
    },
    /// A format version this build does not read.
    #[error(
        "map {path} has format version {found}; this dwslam reads versions 1 to {FORMAT_VERSION} (a map from a newer dwslam?)"
    )]
    Version {
        /// The file.
        path: PathBuf,
        /// Its version.
        found: u32,
    },
    /// The contents do not decode, or describe no valid map.
    #[error("map {path} is malformed: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The map was made with another camera, sensor or vocabulary than the run's.
    #[error("map {path} was made with {what} {map}; this run has {run}")]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// What differs.
        what: &'static str,
        /// The map's.
        map: String,
        /// The run's.
        run: String,
    },
}

/// The camera a map was made with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapCamera {
    /// Mono, stereo or RGB-D.
    pub kind: SensorKind,
    /// Focal lengths and principal point (pixels).
    pub fx: f64,
    /// See `fx`.
    pub fy: f64,
    /// See `fx`.
    pub cx: f64,
    /// See `fx`.
    pub cy: f64,
    /// Stereo baseline (metres; RGB-D: the virtual one), `None` for mono.
    pub baseline: Option<f64>,
}

impl MapCamera {
    /// The camera of `sensor`.
    pub fn of(sensor: &SensorModel) -> Self {
        let p = sensor.pinhole();
        MapCamera {
            kind: sensor.kind(),
            fx: p.fx,
            fy: p.fy,
            cx: p.cx,
            cy: p.cy,
            baseline: match sensor {
                SensorModel::Mono(_) => None,
                SensorModel::Stereo(s) => Some(s.baseline),
                SensorModel::Rgbd(r) => Some(r.stereo.baseline),
            },
        }
    }

    fn pinhole(&self) -> PinholeCamera {
        PinholeCamera::new(self.fx, self.fy, self.cx, self.cy)
    }
}

impl std::fmt::Display for MapCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} fx {} fy {} cx {} cy {}",
            self.kind, self.fx, self.fy, self.cx, self.cy
        )?;
        if let Some(b) = self.baseline {
            write!(f, " baseline {b} m")?;
        }
        Ok(())
    }
}

/// The vocabulary a map's features are described in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct VocabularyId {
    /// Its number of words.
    pub words: u64,
    /// [`Vocabulary::fingerprint`].
    pub fingerprint: u64,
}

impl VocabularyId {
    /// The identity of `vocabulary`.
    pub fn of(vocabulary: &Vocabulary) -> Self {
        VocabularyId {
            words: vocabulary.num_words() as u64,
            fingerprint: vocabulary.fingerprint(),
        }
    }
}

impl std::fmt::Display for VocabularyId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} words, fingerprint {:016x}",
            self.words, self.fingerprint
        )
    }
}

/// What a map file says about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapAbout {
    /// The dwslam version that wrote it.
    pub dwslam: String,
    /// The camera.
    pub camera: MapCamera,
    /// The vocabulary of its keyframes' features (`None`: made without one; it cannot be
    /// relocalised in).
    pub vocabulary: Option<VocabularyId>,
    /// The configuration overrides of the run that made it (YAML; empty: the defaults of
    /// `dwslam`).
    pub config: String,
    /// The sequences it was made from, oldest first.
    pub sequences: Vec<String>,
}

/// A map as a file holds it (see the [module docs](self)).
pub struct MapFile {
    /// The file it was read from (empty for a map not read from a file).
    pub path: PathBuf,
    /// What it says about itself.
    pub about: MapAbout,
    /// The graph.
    pub graph: RunGraph,
    /// The keyframes' images (grey only, and only where the guided search reads them).
    pub keyframes: KeyframeStore,
    /// The keyframes' place-recognition features.
    pub(crate) features: Vec<(KeyframeId, KeyframeFeatures)>,
    /// The file's bytes by part, if read from one.
    bytes: Option<MapBytes>,
}

impl std::fmt::Debug for MapFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapFile")
            .field("path", &self.path)
            .field("about", &self.about)
            .field("summary", &self.summary())
            .finish()
    }
}

/// A sum of what a map holds (`dwslam map info`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MapSummary {
    /// Keyframes.
    pub keyframes: usize,
    /// Points.
    pub points: usize,
    /// Maps with keyframes (several after losses not merged or joined yet).
    pub maps: usize,
    /// Covisibility edges (each counted once), of which marginalised (loops among them).
    pub edges: usize,
    /// See `edges`.
    pub marginalised_edges: usize,
    /// Measurements of points by keyframes.
    pub observations: usize,
    /// ORB keypoints of all keyframes.
    pub keypoints: usize,
    /// Image pixels kept.
    pub pixels: usize,
    /// The file's bytes by part (a map read from a file).
    pub bytes: Option<MapBytes>,
}

/// A map file's bytes by part.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct MapBytes {
    /// The whole file.
    pub total: usize,
    /// The graph: keyframes' poses, measurements and edges, points.
    pub graph: usize,
    /// The keyframes' place-recognition features (keypoints, descriptors, their 3D points).
    pub features: usize,
    /// The keyframes' images where the guided search reads them (compressed).
    pub images: usize,
}

impl MapFile {
    /// What the map holds.
    pub fn summary(&self) -> MapSummary {
        fn of<const N: usize>(g: &SlamGraph<N>) -> (usize, usize, usize, usize, usize, usize) {
            let maps: std::collections::BTreeSet<usize> =
                g.keyframes().map(|(_, k)| k.map()).collect();
            let edges = g.keyframes().map(|(_, k)| k.edges().len()).sum::<usize>() / 2;
            let marginalised = g
                .keyframes()
                .map(|(_, k)| k.edges().values().filter(|e| e.relative.is_some()).count())
                .sum::<usize>()
                / 2;
            let observations = g.keyframes().map(|(_, k)| k.observations().len()).sum();
            (
                g.num_keyframes(),
                g.num_points(),
                maps.len(),
                edges,
                marginalised,
                observations,
            )
        }
        let (keyframes, points, maps, edges, marginalised_edges, observations) = match &self.graph {
            RunGraph::Depth(g) => of(g),
            RunGraph::Mono(g) => of(g),
        };
        MapSummary {
            keyframes,
            points,
            maps,
            edges,
            marginalised_edges,
            observations,
            keypoints: self.features.iter().map(|(_, f)| f.keypoints.len()).sum(),
            pixels: self
                .keyframes
                .iter()
                .map(|(_, k)| k.gray.data().iter().filter(|&&p| p != 0).count())
                .sum(),
            bytes: self.bytes,
        }
    }

    /// Checks that a run with `sensor` and `vocabulary` can use the map read from `path`.
    pub fn check(
        &self,
        path: &Path,
        sensor: &SensorModel,
        vocabulary: Option<&Vocabulary>,
    ) -> Result<(), MapFileError> {
        let mismatch = |what, map: String, run: String| MapFileError::Mismatch {
            path: path.to_path_buf(),
            what,
            map,
            run,
        };
        let run = MapCamera::of(sensor);
        let mine = &self.about.camera;
        if run.kind != mine.kind {
            return Err(mismatch(
                "the sensor",
                mine.kind.to_string(),
                run.kind.to_string(),
            ));
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
        let same = close(run.fx, mine.fx)
            && close(run.fy, mine.fy)
            && close(run.cx, mine.cx)
            && close(run.cy, mine.cy)
            && match (run.baseline, mine.baseline) {
                (Some(a), Some(b)) => close(a, b),
                (None, None) => true,
                _ => false,
            };
        if !same {
            return Err(mismatch("the camera", mine.to_string(), run.to_string()));
        }
        match (self.about.vocabulary, vocabulary.map(VocabularyId::of)) {
            (Some(a), Some(b)) if a != b => {
                Err(mismatch("the vocabulary", a.to_string(), b.to_string()))
            }
            (Some(a), None) => Err(mismatch(
                "the vocabulary",
                a.to_string(),
                "none (loops.enabled: false)".into(),
            )),
            (None, Some(_)) => Err(mismatch(
                "no vocabulary",
                "(it was made with loops.enabled: false)".into(),
                "one: a map without keyframe features cannot be relocalised in".into(),
            )),
            _ => Ok(()),
        }
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        encode(&self.about, &self.graph, &self.keyframes, &self.features)
    }

    /// The map of a file's bytes (`path` names it in errors).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, MapFileError> {
        let path_buf = || path.to_path_buf();
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            return Err(MapFileError::NotAMap { path: path_buf() });
        }
        if bytes.len() < HEADER_LEN {
            return Err(MapFileError::Truncated {
                path: path_buf(),
                expected: HEADER_LEN as u64,
                found: bytes.len() as u64,
            });
        }
        let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let version = word(8);
        if version == 0 || version > FORMAT_VERSION {
            return Err(MapFileError::Version {
                path: path_buf(),
                found: version,
            });
        }
        let flags = word(12);
        let length = u64::from_le_bytes(bytes[16..24].try_into().unwrap());
        let stored = word(24);
        let found = bytes.len() as u64;
        // Checked: a corrupt length near 2⁶⁴ must not wrap round to the file's (found by
        // `cargo fuzz`, bench/fuzz).
        if (HEADER_LEN as u64).checked_add(length) != Some(found) {
            return Err(MapFileError::Truncated {
                path: path_buf(),
                expected: (HEADER_LEN as u64).saturating_add(length),
                found,
            });
        }
        let body = &bytes[HEADER_LEN..];
        let mut crc = flate2::Crc::new();
        crc.update(body);
        if crc.sum() != stored {
            return Err(MapFileError::Corrupted {
                path: path_buf(),
                stored,
                computed: crc.sum(),
            });
        }
        let malformed = |message: String| MapFileError::Malformed {
            path: path_buf(),
            message,
        };
        if flags != 0 {
            return Err(malformed(format!("unknown flags {flags:#x}")));
        }
        let record: BodyRecord = postcard::from_bytes(body)
            .map_err(|e| malformed(format!("its contents do not decode ({e})")))?;
        let bytes_of = MapBytes {
            total: bytes.len(),
            graph: size(&record.graph),
            features: record
                .keyframes
                .iter()
                .map(|k| k.features.as_ref().map_or(0, size))
                .sum(),
            images: record
                .keyframes
                .iter()
                .map(|k| k.pixels.len() + k.kept.len())
                .sum(),
        };
        let mut map = Self::from_record(record).map_err(malformed)?;
        map.path = path.to_path_buf();
        map.bytes = Some(bytes_of);
        Ok(map)
    }

    /// Writes the map to `path` atomically (a temporary file beside it, synced, then renamed
    /// over it): a reader never sees half a map, a failed write leaves what was there. Returns
    /// the file's size.
    pub fn write(&self, path: &Path) -> Result<u64, MapFileError> {
        write_bytes(path, &self.to_bytes())
    }

    /// Reads the map file `path`.
    pub fn read(path: &Path) -> Result<Self, MapFileError> {
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|mut f| f.read_to_end(&mut bytes))
            .map_err(|source| MapFileError::Read {
                path: path.to_path_buf(),
                source,
            })?;
        Self::from_bytes(&bytes, path)
    }

    fn from_record(record: BodyRecord) -> Result<Self, String> {
        let BodyRecord {
            about,
            graph,
            keyframes: records,
        } = record;
        let graph = match graph.dimension {
            3 => RunGraph::Depth(graph.graph()?),
            2 => RunGraph::Mono(graph.graph()?),
            d => return Err(format!("measurements of dimension {d}")),
        };
        let camera = about.camera.pinhole();
        let mut keyframes = KeyframeStore::new();
        let mut features = Vec::new();
        for r in records {
            let id = KeyframeId(r.id);
            let known = match &graph {
                RunGraph::Depth(g) => g.keyframe(id).is_some(),
                RunGraph::Mono(g) => g.keyframe(id).is_some(),
            };
            if !known || keyframes.get(id).is_some() {
                return Err(format!(
                    "images of {id}, not a keyframe of the graph or given twice"
                ));
            }
            let (images, f) = r.restore(&camera)?;
            keyframes.insert(id, images);
            if let Some(f) = f {
                features.push((id, f));
            }
        }
        Ok(MapFile {
            path: PathBuf::new(),
            about,
            graph,
            keyframes,
            features,
            bytes: None,
        })
    }
}

/// The bytes of a map file of `graph`, `store` and `features` (see [`MapFile::to_bytes`]).
pub(crate) fn encode(
    about: &MapAbout,
    graph: &RunGraph,
    store: &KeyframeStore,
    features: &[(KeyframeId, KeyframeFeatures)],
) -> Vec<u8> {
    let rec = record(about, graph, store, features);
    let body = postcard::to_stdvec(&rec).expect("a map record always serialises");
    let mut crc = flate2::Crc::new();
    crc.update(&body);
    let mut out = Vec::with_capacity(HEADER_LEN + body.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(body.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc.sum().to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// Writes `bytes` to `path` atomically (see [`MapFile::write`]); returns their length.
pub(crate) fn write_bytes(path: &Path, bytes: &[u8]) -> Result<u64, MapFileError> {
    let failed = |source| MapFileError::Write {
        path: path.to_path_buf(),
        source,
    };
    let name = path
        .file_name()
        .ok_or_else(|| failed(std::io::Error::other("the path names no file")))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(failed(e));
    }
    Ok(bytes.len() as u64)
}

fn record(
    about: &MapAbout,
    graph: &RunGraph,
    store: &KeyframeStore,
    features: &[(KeyframeId, KeyframeFeatures)],
) -> BodyRecord {
    let (graph, anchors) = match graph {
        RunGraph::Depth(g) => (GraphRecord::of(g), anchored_pixels(g)),
        RunGraph::Mono(g) => (GraphRecord::of(g), anchored_pixels(g)),
    };
    let features: std::collections::BTreeMap<KeyframeId, &KeyframeFeatures> =
        features.iter().map(|(k, f)| (*k, f)).collect();
    let keyframes = store
        .iter()
        .map(|(id, images)| {
            let pixels = anchors.get(&id).map_or(&[][..], |v| &v[..]);
            KeyframeRecord::of(id, images, pixels, features.get(&id).copied())
        })
        .collect();
    BodyRecord {
        about: about.clone(),
        graph,
        keyframes,
    }
}

/// Each keyframe's pixels of the points it anchors (where the guided search warps their
/// templates from).
fn anchored_pixels<const N: usize>(
    g: &SlamGraph<N>,
) -> std::collections::BTreeMap<KeyframeId, Vec<Vector2<f64>>> {
    let mut out: std::collections::BTreeMap<KeyframeId, Vec<Vector2<f64>>> = Default::default();
    for (p, point) in g.points() {
        if let Some(z) = g
            .keyframe(point.anchor())
            .and_then(|k| k.observations().get(&p))
        {
            out.entry(point.anchor())
                .or_default()
                .push(Vector2::new(z[0], z[1]));
        }
    }
    out
}

/// The encoded size of a record.
fn size<T: Serialize>(record: &T) -> usize {
    postcard::experimental::serialized_size(record).unwrap_or(0)
}

// ---------------------------------------------------------------------------------------------
// The records: the file's schema, version 1 (docs/map-format.md). Changing a record changes
// the format: a new FORMAT_VERSION, and a reader of the old one.

#[derive(Serialize, Deserialize)]
struct BodyRecord {
    about: MapAbout,
    graph: GraphRecord,
    keyframes: Vec<KeyframeRecord>,
}

/// A similarity: unit quaternion `(w, x, y, z)`, translation, scale.
type PoseRecord = [f64; 8];

fn pose_record(t: &Sim3) -> PoseRecord {
    let q = t.rotation().unit_quaternion();
    let p = t.translation();
    [q.w, q.i, q.j, q.k, p.x, p.y, p.z, t.scale()]
}

fn pose(r: &PoseRecord) -> Result<Sim3, String> {
    let q = Quaternion::new(r[0], r[1], r[2], r[3]);
    if !r.iter().all(|v| v.is_finite()) || (q.norm() - 1.0).abs() > 1e-6 {
        return Err(format!("a pose {r:?} that is no similarity"));
    }
    // The stored quaternion as it was (normalised on write): re-normalising would change its
    // last bits, and a map saved again would differ from the one read.
    Sim3::new(
        So3::from_unit_quaternion(UnitQuaternion::new_unchecked(q)),
        Vector3::new(r[4], r[5], r[6]),
        r[7],
    )
    .map_err(|e| e.to_string())
}

#[derive(Serialize, Deserialize)]
struct GraphRecord {
    /// Measurement dimension: 3 (stereo, RGB-D: `(u, v, u_r)`) or 2 (mono).
    dimension: u8,
    keyframes: Vec<KeyframeNodeRecord>,
    points: Vec<PointRecord>,
    ids_issued: (u64, u64),
    reference: Option<u32>,
    version: u64,
    current_map: u64,
    maps_started: u64,
    merges: Vec<(u64, u64, PoseRecord)>,
    joins: Vec<(u32, u32, PoseRecord, u64)>,
}

#[derive(Serialize, Deserialize)]
struct KeyframeNodeRecord {
    id: u32,
    pose: PoseRecord,
    pose_version: u64,
    map: u64,
    /// The points it measures, ascending.
    points: Vec<u32>,
    /// Their measurements, `dimension` numbers each.
    measurements: Vec<f64>,
    /// `(other end, weight, T_ji if marginalised)`, ascending.
    edges: Vec<(u32, u64, Option<PoseRecord>)>,
}

#[derive(Serialize, Deserialize)]
struct PointRecord {
    id: u32,
    anchor: u32,
    inverse_depth: [f64; 3],
    version: u64,
}

impl GraphRecord {
    fn of<const N: usize>(g: &SlamGraph<N>) -> Self {
        let parts = g.to_parts();
        GraphRecord {
            dimension: N as u8,
            keyframes: parts
                .keyframes
                .iter()
                .map(|k| KeyframeNodeRecord {
                    id: k.id.0,
                    pose: pose_record(&k.camera_from_world),
                    pose_version: k.pose_version,
                    map: k.map as u64,
                    points: k.observations.iter().map(|(p, _)| p.0).collect(),
                    measurements: k
                        .observations
                        .iter()
                        .flat_map(|(_, z)| z.iter().copied())
                        .collect(),
                    edges: k
                        .edges
                        .iter()
                        .map(|(j, e)| (j.0, e.weight as u64, e.relative.as_ref().map(pose_record)))
                        .collect(),
                })
                .collect(),
            points: parts
                .points
                .iter()
                .map(|p| PointRecord {
                    id: p.id.0,
                    anchor: p.anchor.0,
                    inverse_depth: p.inverse_depth.into(),
                    version: p.version,
                })
                .collect(),
            ids_issued: (parts.ids_issued.0 as u64, parts.ids_issued.1 as u64),
            reference: parts.reference.map(|r| r.0),
            version: parts.version,
            current_map: parts.current_map as u64,
            maps_started: parts.maps_started as u64,
            merges: parts
                .merges
                .iter()
                .map(|m| (m.from as u64, m.into as u64, pose_record(&m.moved)))
                .collect(),
            joins: parts
                .joins
                .iter()
                .map(|j| {
                    (
                        j.current.0,
                        j.old.0,
                        pose_record(&j.current_from_old),
                        j.inliers as u64,
                    )
                })
                .collect(),
        }
    }

    fn graph<const N: usize>(self) -> Result<SlamGraph<N>, String> {
        // Counts bounded by what a file of this size can describe: a corrupt count is refused
        // before it allocates.
        let size = |n: u64, what: &str| -> Result<usize, String> {
            usize::try_from(n)
                .ok()
                .filter(|&n| n <= u32::MAX as usize)
                .ok_or_else(|| format!("{what} {n} out of range"))
        };
        let ids = |n: usize, what: &str| -> Result<usize, String> {
            if n > 1 << 24 {
                Err(format!("{n} {what} ids issued, more than 2^24"))
            } else {
                Ok(n)
            }
        };
        let mut keyframes = Vec::with_capacity(self.keyframes.len());
        for k in self.keyframes {
            if k.measurements.len() != k.points.len() * N {
                return Err(format!(
                    "keyframe {}: {} numbers for {} measurements of dimension {N}",
                    k.id,
                    k.measurements.len(),
                    k.points.len()
                ));
            }
            let mut edges = Vec::with_capacity(k.edges.len());
            for (j, weight, relative) in k.edges {
                edges.push((
                    KeyframeId(j),
                    Edge {
                        weight: size(weight, "edge weight")?,
                        relative: relative.as_ref().map(pose).transpose()?,
                    },
                ));
            }
            keyframes.push(KeyframePart {
                id: KeyframeId(k.id),
                camera_from_world: pose(&k.pose)?,
                pose_version: k.pose_version,
                map: size(k.map, "map")?,
                observations: k
                    .points
                    .iter()
                    .zip(k.measurements.chunks_exact(N))
                    .map(|(&p, z)| (PointId(p), SVector::<f64, N>::from_column_slice(z)))
                    .collect(),
                edges,
            });
        }
        let parts = GraphParts {
            keyframes,
            points: self
                .points
                .into_iter()
                .map(|p| PointPart {
                    id: PointId(p.id),
                    anchor: KeyframeId(p.anchor),
                    inverse_depth: p.inverse_depth.into(),
                    version: p.version,
                })
                .collect(),
            // The graph holds a slot per id ever issued: a corrupt count must not make the
            // reader allocate gigabytes (2²⁴ ids of each: beyond any map held in memory).
            ids_issued: (
                size(self.ids_issued.0, "keyframe ids").and_then(|n| ids(n, "keyframe"))?,
                size(self.ids_issued.1, "point ids").and_then(|n| ids(n, "point"))?,
            ),
            reference: self.reference.map(KeyframeId),
            version: self.version,
            current_map: size(self.current_map, "current map")?,
            maps_started: size(self.maps_started, "maps started")?,
            merges: self
                .merges
                .iter()
                .map(|(from, into, moved)| {
                    Ok(MapMerge {
                        from: size(*from, "map")?,
                        into: size(*into, "map")?,
                        moved: pose(moved)?,
                    })
                })
                .collect::<Result<_, String>>()?,
            joins: self
                .joins
                .iter()
                .map(|(current, old, s, inliers)| {
                    Ok(MapJoin {
                        current: KeyframeId(*current),
                        old: KeyframeId(*old),
                        current_from_old: pose(s)?,
                        inliers: size(*inliers, "inliers")?,
                    })
                })
                .collect::<Result<_, String>>()?,
        };
        SlamGraph::from_parts(parts).map_err(|e| e.to_string())
    }
}

#[derive(Serialize, Deserialize)]
struct KeyframeRecord {
    id: u32,
    frame_index: u64,
    timestamp: f64,
    width: u32,
    height: u32,
    /// One bit per `BLOCK`×`BLOCK` block of the image, row-major: kept or not.
    kept: Vec<u8>,
    /// The kept blocks' pixels (row by row within each block, blocks in order; blocks at the
    /// right and bottom edges clipped to the image), zlib-compressed.
    pixels: Vec<u8>,
    features: Option<FeaturesRecord>,
}

#[derive(Serialize, Deserialize)]
struct FeaturesRecord {
    /// `(u, v, angle, response, scale)` and the pyramid level of each keypoint.
    keypoints: Vec<([f32; 5], u8)>,
    descriptors: Vec<[u64; 4]>,
    /// The camera-frame point of each keypoint, where its depth is known.
    points: Vec<Option<[f64; 3]>>,
    /// Monocular maps: `(u, v, depth)` of the keyframe's map points.
    depth_samples: Vec<[f64; 3]>,
}

/// The prediction of pixel `(u, v)` of a block whose first pixel is `(u0, v0)` from the
/// pixels before it in the block (row by row): the plane through the left, upper and
/// upper-left neighbours, clamped (PNG's and JPEG-LS's idea: the residuals of a smooth image
/// are small, and deflate halves them where it barely touches raw pixels).
fn predict_pixel(
    at: impl Fn(usize, usize) -> u8,
    (u, v): (usize, usize),
    (u0, v0): (usize, usize),
) -> u8 {
    match (u > u0, v > v0) {
        (true, true) => {
            let (l, t, c) = (
                at(u - 1, v) as i32,
                at(u, v - 1) as i32,
                at(u - 1, v - 1) as i32,
            );
            (l + t - c).clamp(l.min(t), l.max(t)) as u8
        }
        (true, false) => at(u - 1, v),
        (false, true) => at(u, v - 1),
        (false, false) => 128,
    }
}

/// The blocks of a `width`×`height` image: `(columns, rows)`.
fn blocks(width: usize, height: usize) -> (usize, usize) {
    (width.div_ceil(BLOCK), height.div_ceil(BLOCK))
}

/// The pixel rectangle `(u0, v0, u1, v1)` of block `(bu, bv)`.
fn block_rect(bu: usize, bv: usize, width: usize, height: usize) -> (usize, usize, usize, usize) {
    let (u0, v0) = (bu * BLOCK, bv * BLOCK);
    (u0, v0, (u0 + BLOCK).min(width), (v0 + BLOCK).min(height))
}

impl KeyframeRecord {
    fn of(
        id: KeyframeId,
        images: &KeyframeImages,
        anchored: &[Vector2<f64>],
        features: Option<&KeyframeFeatures>,
    ) -> Self {
        let gray = &images.gray;
        let (w, h) = (gray.width(), gray.height());
        let (bw, bh) = blocks(w, h);
        let mut kept = vec![0u8; (bw * bh).div_ceil(8)];
        let block_of = |x: f64, n: usize| ((x.max(0.0) as usize) / BLOCK).min(n - 1);
        for z in anchored {
            if !(z.x.is_finite() && z.y.is_finite()) {
                continue;
            }
            let r = TEMPLATE_REACH_PX;
            for bv in block_of(z.y - r, bh)..=block_of(z.y + r, bh) {
                for bu in block_of(z.x - r, bw)..=block_of(z.x + r, bw) {
                    let i = bv * bw + bu;
                    kept[i / 8] |= 1 << (i % 8);
                }
            }
        }
        let mut raw = Vec::new();
        for i in 0..bw * bh {
            if kept[i / 8] & (1 << (i % 8)) != 0 {
                let (u0, v0, u1, v1) = block_rect(i % bw, i / bw, w, h);
                for v in v0..v1 {
                    for u in u0..u1 {
                        let at = |u, v| gray.get(u, v);
                        let p = predict_pixel(at, (u, v), (u0, v0));
                        raw.push(gray.get(u, v).wrapping_sub(p));
                    }
                }
            }
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        z.write_all(&raw).expect("compressing into memory");
        KeyframeRecord {
            id: id.0,
            frame_index: images.frame_index as u64,
            timestamp: images.timestamp,
            width: w as u32,
            height: h as u32,
            kept,
            pixels: z.finish().expect("compressing into memory"),
            features: features.map(|f| FeaturesRecord {
                keypoints: f
                    .keypoints
                    .iter()
                    .map(|k| ([k.u, k.v, k.angle, k.response, k.scale], k.level as u8))
                    .collect(),
                descriptors: f.descriptors.clone(),
                points: f.points.iter().map(|p| p.map(Into::into)).collect(),
                depth_samples: f
                    .depth_samples
                    .iter()
                    .map(|(p, d)| [p.x, p.y, *d])
                    .collect(),
            }),
        }
    }

    fn restore(
        self,
        camera: &PinholeCamera,
    ) -> Result<(KeyframeImages, Option<KeyframeFeatures>), String> {
        let id = KeyframeId(self.id);
        let (w, h) = (self.width as usize, self.height as usize);
        // A keyframe's image: at most 2¹⁴ pixels a side (KITTI's is 1241×376).
        if w == 0 || h == 0 || w > 1 << 14 || h > 1 << 14 {
            return Err(format!("{id}: an image of {w}×{h} pixels"));
        }
        let (bw, bh) = blocks(w, h);
        if self.kept.len() != (bw * bh).div_ceil(8) {
            return Err(format!("{id}: a block mask of the wrong size"));
        }
        let is_kept = |i: usize| self.kept[i / 8] & (1 << (i % 8)) != 0;
        let expected: usize = (0..bw * bh)
            .filter(|&i| is_kept(i))
            .map(|i| {
                let (u0, v0, u1, v1) = block_rect(i % bw, i / bw, w, h);
                (u1 - u0) * (v1 - v0)
            })
            .sum();
        let mut raw = Vec::with_capacity(expected);
        flate2::read::ZlibDecoder::new(&self.pixels[..])
            .take(expected as u64 + 1)
            .read_to_end(&mut raw)
            .map_err(|e| format!("{id}: its pixels do not decompress ({e})"))?;
        if raw.len() != expected {
            return Err(format!(
                "{id}: {} pixels for {expected} in its kept blocks",
                raw.len()
            ));
        }
        let mut gray = GrayImage::new(w, h);
        let mut at = 0;
        for i in (0..bw * bh).filter(|&i| is_kept(i)) {
            let (u0, v0, u1, v1) = block_rect(i % bw, i / bw, w, h);
            for v in v0..v1 {
                for u in u0..u1 {
                    let p = predict_pixel(|u, v| gray.get(u, v), (u, v), (u0, v0));
                    gray.set(u, v, raw[at].wrapping_add(p));
                    at += 1;
                }
            }
        }
        let images = KeyframeImages {
            frame_index: usize::try_from(self.frame_index).map_err(|e| e.to_string())?,
            timestamp: self.timestamp,
            gray,
            depth: None,
            colour: None,
        };
        let features = match self.features {
            None => None,
            Some(f) => {
                let n = f.keypoints.len();
                if f.descriptors.len() != n || f.points.len() != n {
                    return Err(format!(
                        "{id}: {n} keypoints, {} descriptors, {} points",
                        f.descriptors.len(),
                        f.points.len()
                    ));
                }
                Some(KeyframeFeatures {
                    keypoints: f
                        .keypoints
                        .iter()
                        .map(|&([u, v, angle, response, scale], level)| KeyPoint {
                            u,
                            v,
                            angle,
                            response,
                            level: level as usize,
                            scale,
                        })
                        .collect(),
                    descriptors: f.descriptors,
                    points: f.points.into_iter().map(|p| p.map(Into::into)).collect(),
                    depth_samples: f
                        .depth_samples
                        .iter()
                        .map(|s| (Vector2::new(s[0], s[1]), s[2]))
                        .collect(),
                    camera: *camera,
                })
            }
        };
        Ok((images, features))
    }
}
