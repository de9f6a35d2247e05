//! The binary vocabulary of place recognition (thesis §6.4.2): trained offline, reproducibly,
//! on images disjoint from every test sequence, written as a DBoW2 YAML file, and loaded (or
//! trained on the fly and cached) by the live system.
//!
//! # Training set
//!
//! The thesis trained its SURF dictionary on ~150 images of the INRIA Holidays set, images
//! that none of its experiments saw. The default training set here ([`DEFAULT_TRAINING_SET`])
//! is every real image in the shared data that belongs to no test sequence (7-Scenes Red
//! Kitchen, the KITTI snippet, the EuRoC micro clip and the rendered sequences are the test
//! sequences):
//!
//! - `slambook2_sample_images/bow_training_images` (10 TUM RGB-D-style indoor frames),
//!   `rgbd_pair` (two TUM RGB-D frames; `1.png` is byte-identical to
//!   `bow_training_images/1.png` and is dropped as a duplicate) and `kitti_stereo_pair` (a
//!   1241×376 KITTI pair with the calibration of KITTI sequences 00–02, while the test snippet
//!   is 1226×370 from sequences 04–12: a different sequence);
//! - the Middlebury stereo pairs (`tsukuba`, `venus`, `teddy`; the ground-truth disparity
//!   images are not camera images and are left out);
//! - the three colour frames of the TUM RGB-D `freiburg1_xyz` fragment.
//!
//! Images identical in content (file bytes) are used once.
//!
//! # Tree shape
//!
//! A word is a cluster of training descriptors; its centre and its idf are only meaningful if
//! several descriptors fell into it. The thesis clustered ~150 images × 500–2000 SURF
//! keypoints into ~10,000 words: about ten descriptors per word. [`tree_shape`] therefore aims
//! at [`DESCRIPTORS_PER_WORD`] = 10 descriptors per word, `W = N/10` words for `N` training
//! descriptors, and picks the fewest levels `L` whose tree with DBoW2's branching `k ≤ 10` can
//! hold `W` leaves, then the smallest `k` with `k^L ≥ W` (for the thesis's `W = 10⁴`: `k = 10`,
//! `L = 4`). Few levels keep the greedy descent's quantisation error small; `k ≤ 10` keeps the
//! descent cheap (`k·L` Hamming distances per descriptor).
//!
//! # Files and the cache
//!
//! [`write_dbow2_yaml`] writes the DBoW2 text format (OpenCV `FileStorage` YAML, as DBoW2's
//! `TemplatedVocabulary::save` writes it; `vision::bow::Vocabulary::load_dbow_yaml` and DBoW2
//! read it). The descriptors are dwslam's ORB (its own BRIEF pattern, see `vision::orb`), so
//! the file is readable by other tools but its words only describe dwslam's descriptors.
//!
//! The default vocabulary — the default training set with the default ORB extractor — ships
//! inside the binary ([`DEFAULT_VOCABULARY_GZ`], 138 kB; `dwslam vocabulary` reproduces it
//! exactly, which a test checks), so that place recognition needs no data on a fresh machine.
//!
//! [`load_vocabulary`] loads a given file, or the shipped default, or (for other ORB
//! parameters) trains the default training set and caches it in [`cache_dir`] (`$XDG_CACHE_HOME/dwslam`, else `~/.cache/dwslam`; never inside
//! the repository) under a name holding the hash of the training images' bytes and of every
//! training parameter, so that a changed training set or parameter trains anew.

use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use vision::bow::{BowError, Vocabulary};
use vision::orb::{Descriptor, OrbParams, detect_and_describe};

/// The default training images and folders, relative to the shared data folder
/// (`data::paths::dataset_root`); see the [module docs](self) for why these.
pub const DEFAULT_TRAINING_SET: &[&str] = &[
    "slambook2_sample_images/bow_training_images",
    "slambook2_sample_images/rgbd_pair/1.png",
    "slambook2_sample_images/rgbd_pair/2.png",
    "slambook2_sample_images/kitti_stereo_pair",
    "middlebury_stereo/tsukuba/im3.png",
    "middlebury_stereo/tsukuba/im4.png",
    "middlebury_stereo/venus/im2.png",
    "middlebury_stereo/venus/im6.png",
    "middlebury_stereo/teddy/im2.png",
    "middlebury_stereo/teddy/im6.png",
    "tum_rgbd_fr1_xyz_fragment/rgb",
];

/// The default vocabulary (gzip'd DBoW2 YAML): `dwslam vocabulary` on
/// [`DEFAULT_TRAINING_SET`] with `OrbConfig::default()`.
pub const DEFAULT_VOCABULARY_GZ: &[u8] = include_bytes!("../../assets/default_vocabulary.yml.gz");

/// Parses the shipped default vocabulary.
pub fn default_vocabulary() -> Result<Vocabulary, VocabularyError> {
    use std::io::Read;
    let mut text = String::new();
    flate2::read::GzDecoder::new(DEFAULT_VOCABULARY_GZ)
        .read_to_string(&mut text)
        .map_err(|e| VocabularyError::NoImages(format!("the shipped vocabulary: {e}")))?;
    Vocabulary::parse_dbow_yaml(&text)
        .map_err(|e| VocabularyError::NoImages(format!("the shipped vocabulary: {e}")))
}

/// Training descriptors per word the tree shape aims at (the thesis's ~10: see the
/// [module docs](self)).
pub const DESCRIPTORS_PER_WORD: usize = 10;

/// The largest branching factor: DBoW2's and ORB-SLAM's `k = 10` (Nistér & Stewénius 2006
/// found `k = 10` a good trade of descent cost against quantisation).
pub const MAX_BRANCHING: usize = 10;

/// Lloyd iterations per node of the k-majority clustering: binary k-majority converges in a
/// handful of iterations (the assignment rarely changes after ~10); 20 leaves a margin at
/// small cost.
pub const TRAINING_ITERATIONS: usize = 20;

/// Seed of the clustering (k-means++ seeding), fixed so that training is reproducible.
pub const TRAINING_SEED: u64 = 0x0d_b0_a2;

/// Bumped whenever training changes in a way the parameters do not show, so that cached
/// vocabularies of the old training are not reused.
const TRAINING_VERSION: u32 = 1;

/// Why a vocabulary could not be trained, written or loaded.
#[derive(Debug, thiserror::Error)]
pub enum VocabularyError {
    /// A training image or folder could not be read.
    #[error("training image {}: {message}", path.display())]
    Image {
        /// The file or folder.
        path: PathBuf,
        /// What was wrong.
        message: String,
    },
    /// No training images were given or found.
    #[error("no training images: {0}")]
    NoImages(String),
    /// Clustering failed, or a vocabulary file is malformed.
    #[error(transparent)]
    Bow(#[from] BowError),
    /// A vocabulary file could not be written.
    #[error("cannot write vocabulary {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// `(k, L)` for a training set of `descriptors` descriptors (see the [module docs](self)):
/// `W = max(2, N / DESCRIPTORS_PER_WORD)` words, the fewest levels `L` with
/// `MAX_BRANCHING^L ≥ W`, then the smallest `k ≥ 2` with `k^L ≥ W`.
pub fn tree_shape(descriptors: usize) -> (usize, usize) {
    let words = (descriptors / DESCRIPTORS_PER_WORD).max(2);
    let fits = |k: usize, levels: usize| {
        (0..levels)
            .try_fold(1usize, |acc, _| acc.checked_mul(k))
            .is_none_or(|n| n >= words)
    };
    let levels = (1..).find(|&l| fits(MAX_BRANCHING, l)).unwrap_or(1);
    let k = (2..=MAX_BRANCHING)
        .find(|&k| fits(k, levels))
        .unwrap_or(MAX_BRANCHING);
    (k, levels)
}

/// The image files of a list of files and folders, in order: a file as given, a folder's
/// images (`.png`, `.jpg`, `.jpeg`, `.pgm`, `.ppm`, `.pnm`, case-insensitive) sorted by name,
/// recursively. Errors name a path that does not exist or a folder without images.
pub fn collect_images(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, VocabularyError> {
    let mut out = Vec::new();
    for input in inputs {
        let meta = std::fs::metadata(input).map_err(|e| VocabularyError::Image {
            path: input.clone(),
            message: e.to_string(),
        })?;
        if meta.is_dir() {
            let before = out.len();
            list_images(input, &mut out)?;
            if out.len() == before {
                return Err(VocabularyError::Image {
                    path: input.clone(),
                    message: "the folder holds no images (.png, .jpg, .pgm, .ppm)".into(),
                });
            }
        } else {
            out.push(input.clone());
        }
    }
    if out.is_empty() {
        return Err(VocabularyError::NoImages("the list is empty".into()));
    }
    Ok(out)
}

fn is_image(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["png", "jpg", "jpeg", "pgm", "ppm", "pnm"]
            .iter()
            .any(|x| e.eq_ignore_ascii_case(x))
    })
}

fn list_images(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), VocabularyError> {
    let err = |e: std::io::Error| VocabularyError::Image {
        path: dir.to_path_buf(),
        message: e.to_string(),
    };
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(err)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()
        .map_err(err)?;
    entries.sort();
    for p in entries {
        if p.is_dir() {
            list_images(&p, out)?;
        } else if is_image(&p) {
            out.push(p);
        }
    }
    Ok(())
}

/// The default training images ([`DEFAULT_TRAINING_SET`]) under the shared data folder `root`.
pub fn default_training_images(root: &Path) -> Result<Vec<PathBuf>, VocabularyError> {
    let inputs: Vec<PathBuf> = DEFAULT_TRAINING_SET.iter().map(|r| root.join(r)).collect();
    collect_images(&inputs)
}

/// 64-bit FNV-1a, the content hash of cache keys and duplicate detection (not adversarial
/// input, so a non-cryptographic hash suffices; written here to need no crate).
#[derive(Clone, Copy, Debug)]
struct Fnv1a(u64);

impl Fnv1a {
    fn new() -> Self {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.write(&x.to_le_bytes());
    }
}

/// Everything training depends on besides the images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainingParams {
    /// The ORB extractor (must be the one the live system uses on its keyframes).
    pub orb: OrbParams,
    /// `(k, L)`; `None`: [`tree_shape`] of the number of training descriptors.
    pub shape: Option<(usize, usize)>,
    /// Lloyd iterations per node.
    pub iterations: usize,
    /// Clustering seed.
    pub seed: u64,
}

impl TrainingParams {
    /// The defaults for an ORB extractor: shape from the training set,
    /// [`TRAINING_ITERATIONS`], [`TRAINING_SEED`].
    pub fn new(orb: OrbParams) -> Self {
        TrainingParams {
            orb,
            shape: None,
            iterations: TRAINING_ITERATIONS,
            seed: TRAINING_SEED,
        }
    }

    fn hash_into(&self, h: &mut Fnv1a) {
        h.write_u64(TRAINING_VERSION as u64);
        h.write_u64(self.orb.num_features as u64);
        h.write(&self.orb.scale_factor.to_le_bytes());
        h.write_u64(self.orb.num_levels as u64);
        h.write_u64(self.orb.edge_threshold as u64);
        h.write_u64(self.orb.fast_threshold as u64);
        let (k, l) = self.shape.unwrap_or((0, 0));
        h.write_u64(k as u64);
        h.write_u64(l as u64);
        h.write_u64(self.iterations as u64);
        h.write_u64(self.seed);
    }
}

/// The training images read into memory, duplicates (identical bytes) dropped, with the
/// content hash of the set and the parameters.
#[derive(Clone, Debug)]
pub struct TrainingSet {
    /// The images used, in order.
    pub images: Vec<PathBuf>,
    /// Images left out because their bytes equal an earlier image's.
    pub duplicates: Vec<PathBuf>,
    bytes: Vec<Vec<u8>>,
    /// Hash of the images' bytes (in order) and of the [`TrainingParams`]: the cache key.
    pub key: u64,
    params: TrainingParams,
}

impl TrainingSet {
    /// Reads the images (files, not folders: see [`collect_images`]).
    pub fn read(images: &[PathBuf], params: TrainingParams) -> Result<Self, VocabularyError> {
        if images.is_empty() {
            return Err(VocabularyError::NoImages("the list is empty".into()));
        }
        let mut seen = std::collections::HashSet::new();
        let mut set = TrainingSet {
            images: Vec::new(),
            duplicates: Vec::new(),
            bytes: Vec::new(),
            key: 0,
            params,
        };
        let mut key = Fnv1a::new();
        params.hash_into(&mut key);
        for path in images {
            let bytes = std::fs::read(path).map_err(|e| VocabularyError::Image {
                path: path.clone(),
                message: e.to_string(),
            })?;
            let mut h = Fnv1a::new();
            h.write(&bytes);
            if !seen.insert((bytes.len(), h.0)) {
                set.duplicates.push(path.clone());
                continue;
            }
            key.write_u64(bytes.len() as u64);
            key.write_u64(h.0);
            set.images.push(path.clone());
            set.bytes.push(bytes);
        }
        set.key = key.0;
        Ok(set)
    }

    /// Extracts the ORB descriptors of every image (in parallel, in order), calling
    /// `progress(done, total)` after each image.
    pub fn descriptors(
        &self,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Vec<Vec<Descriptor>>, VocabularyError> {
        let done = std::sync::atomic::AtomicUsize::new(0);
        let total = self.images.len();
        self.images
            .par_iter()
            .zip(&self.bytes)
            .map(|(path, bytes)| {
                let image =
                    vision::image::decode_gray_u8(bytes).map_err(|e| VocabularyError::Image {
                        path: path.clone(),
                        message: e.to_string(),
                    })?;
                let (_, d) = detect_and_describe(&image, &self.params.orb).map_err(|e| {
                    VocabularyError::Image {
                        path: path.clone(),
                        message: e.to_string(),
                    }
                })?;
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(n, total);
                Ok(d)
            })
            .collect()
    }
}

/// A trained vocabulary and how it came about.
#[derive(Clone, Debug)]
pub struct Trained {
    /// The vocabulary.
    pub vocabulary: Vocabulary,
    /// Training descriptors.
    pub descriptors: usize,
    /// Seconds spent extracting descriptors.
    pub extraction_seconds: f64,
    /// Seconds spent clustering.
    pub clustering_seconds: f64,
}

/// Trains a vocabulary on a training set (hierarchical k-majority with k-means++ seeding,
/// `vision::bow::Vocabulary::train`), with the shape of [`tree_shape`] unless the parameters
/// fix it. `progress(done, total)` is called after each image's extraction.
pub fn train(
    set: &TrainingSet,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Trained, VocabularyError> {
    let t0 = Instant::now();
    let descriptors = set.descriptors(progress)?;
    let extraction_seconds = t0.elapsed().as_secs_f64();
    let n: usize = descriptors.iter().map(Vec::len).sum();
    if n == 0 {
        return Err(VocabularyError::NoImages(format!(
            "{} images gave no ORB features",
            set.images.len()
        )));
    }
    let (k, levels) = set.params.shape.unwrap_or_else(|| tree_shape(n));
    let t1 = Instant::now();
    let vocabulary = Vocabulary::train(
        &descriptors,
        k,
        levels,
        set.params.iterations,
        set.params.seed,
    )?;
    Ok(Trained {
        vocabulary,
        descriptors: n,
        extraction_seconds,
        clustering_seconds: t1.elapsed().as_secs_f64(),
    })
}

/// Writes a vocabulary in DBoW2's text format (OpenCV `FileStorage` YAML):
///
/// ```text
/// %YAML:1.0
/// ---
/// vocabulary:
///    k: 10
///    L: 4
///    scoringType: 0          # L1
///    weightingType: 0        # tf-idf
///    nodes:
///       - { nodeId:1, parentId:0, weight:0.,
///           descriptor:"b0 b1 … b31 " }
///    words:
///       - { wordId:0, nodeId:12 }
/// ```
///
/// Descriptor bytes are written in the order `vision::bow` reads them (byte `i` is bits
/// `8i … 8i+7` of the 256-bit descriptor); weights with Rust's shortest round-trip formatting,
/// so that reading the file back gives the same vocabulary.
pub fn write_dbow2_yaml(vocabulary: &Vocabulary, mut out: impl Write) -> std::io::Result<()> {
    writeln!(out, "%YAML:1.0\n---\nvocabulary:")?;
    writeln!(out, "   k: {}\n   L: {}", vocabulary.k, vocabulary.levels)?;
    writeln!(out, "   scoringType: 0\n   weightingType: 0\n   nodes:")?;
    for (id, node) in vocabulary.nodes.iter().enumerate().skip(1) {
        let mut bytes = String::with_capacity(32 * 4);
        for i in 0..32 {
            let b = (node.descriptor[i / 8] >> ((i % 8) * 8)) & 0xff;
            bytes.push_str(&b.to_string());
            bytes.push(' ');
        }
        writeln!(
            out,
            "      - {{ nodeId:{id}, parentId:{}, weight:{:?},\n          descriptor:\"{bytes}\" }}",
            node.parent, node.weight
        )?;
    }
    writeln!(out, "   words:")?;
    for (word, node) in vocabulary.words.iter().enumerate() {
        writeln!(out, "      - {{ wordId:{word}, nodeId:{node} }}")?;
    }
    out.flush()
}

/// Writes a vocabulary file ([`write_dbow2_yaml`]) whole to `PATH.tmp`, then renames it into
/// place, so that an interrupted write never leaves half a vocabulary.
pub fn save(vocabulary: &Vocabulary, path: &Path) -> Result<(), VocabularyError> {
    let err = |source| VocabularyError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{}.tmp", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let file = std::fs::File::create(&tmp).map_err(err)?;
    write_dbow2_yaml(vocabulary, std::io::BufWriter::new(file)).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        err(e)
    })
}

/// Where trained default vocabularies are cached: `$XDG_CACHE_HOME/dwslam`, else
/// `$HOME/.cache/dwslam` (never inside the repository); `None` without either variable.
pub fn cache_dir() -> Option<PathBuf> {
    let nonempty = |v: &str| {
        std::env::var_os(v)
            .filter(|s| !s.is_empty())
            .map(PathBuf::from)
    };
    nonempty("XDG_CACHE_HOME")
        .or_else(|| nonempty("HOME").map(|h| h.join(".cache")))
        .map(|d| d.join("dwslam"))
}

/// The cache file of a training set: `vocabulary-<key>.yml` in `dir`.
pub fn cache_file(dir: &Path, set: &TrainingSet) -> PathBuf {
    dir.join(format!("vocabulary-{:016x}.yml", set.key))
}

/// Where a loaded vocabulary came from.
#[derive(Clone, Debug, PartialEq)]
pub enum VocabularyOrigin {
    /// The file the caller named.
    File(PathBuf),
    /// The default vocabulary shipped in the binary.
    Shipped,
    /// The cache of an earlier training of the same set.
    Cache(PathBuf),
    /// Trained now; cached at the path, or not (with the reason).
    Trained {
        /// Seconds of training (extraction + clustering).
        seconds: f64,
        /// Training descriptors.
        descriptors: usize,
        /// The cache file written, or why none was.
        cached: Result<PathBuf, String>,
    },
}

/// A vocabulary ready for place recognition.
#[derive(Clone, Debug)]
pub struct LoadedVocabulary {
    /// The vocabulary.
    pub vocabulary: std::sync::Arc<Vocabulary>,
    /// Where it came from.
    pub origin: VocabularyOrigin,
}

/// The vocabulary the live system uses: the DBoW2 YAML file `file` (optionally gzip'd) if
/// given; otherwise, for the default ORB parameters, the shipped default vocabulary; for
/// others, the vocabulary of the default training set under the shared data folder
/// `data_root` — from the cache ([`cache_dir`]) if an earlier training of the same
/// images and parameters is there, else trained now (seconds) and cached. A cache that cannot
/// be written or read is not an error: training runs again.
pub fn load_vocabulary(
    file: Option<&Path>,
    data_root: Option<&Path>,
    orb: &OrbParams,
) -> Result<LoadedVocabulary, VocabularyError> {
    load_vocabulary_cached(file, data_root, orb, cache_dir().as_deref())
}

/// [`load_vocabulary`] with the cache in `cache` (none: train every time).
pub fn load_vocabulary_cached(
    file: Option<&Path>,
    data_root: Option<&Path>,
    orb: &OrbParams,
    cache: Option<&Path>,
) -> Result<LoadedVocabulary, VocabularyError> {
    if let Some(path) = file {
        return Ok(LoadedVocabulary {
            vocabulary: std::sync::Arc::new(Vocabulary::load_dbow_yaml(path)?),
            origin: VocabularyOrigin::File(path.to_path_buf()),
        });
    }
    if *orb == crate::place_recognition::OrbConfig::default().params() {
        return Ok(LoadedVocabulary {
            vocabulary: std::sync::Arc::new(default_vocabulary()?),
            origin: VocabularyOrigin::Shipped,
        });
    }
    let root = data_root.ok_or_else(|| {
        VocabularyError::NoImages(
            "no vocabulary file was given and the shared data folder (DWSLAM_DATA) with the \
             default training images was not found"
                .into(),
        )
    })?;
    let set = TrainingSet::read(&default_training_images(root)?, TrainingParams::new(*orb))?;
    let cached = cache.map(|d| cache_file(d, &set));
    if let Some(path) = &cached
        && let Ok(v) = Vocabulary::load_dbow_yaml(path)
    {
        return Ok(LoadedVocabulary {
            vocabulary: std::sync::Arc::new(v),
            origin: VocabularyOrigin::Cache(path.clone()),
        });
    }
    let t0 = Instant::now();
    let trained = train(&set, &|_, _| {})?;
    let seconds = t0.elapsed().as_secs_f64();
    let cached = match cached {
        None => Err("no cache folder (neither XDG_CACHE_HOME nor HOME is set)".to_string()),
        Some(path) => path
            .parent()
            .map_or(Ok(()), std::fs::create_dir_all)
            .map_err(|e| e.to_string())
            .and_then(|()| save(&trained.vocabulary, &path).map_err(|e| e.to_string()))
            .map(|()| path),
    };
    Ok(LoadedVocabulary {
        vocabulary: std::sync::Arc::new(trained.vocabulary),
        origin: VocabularyOrigin::Trained {
            seconds,
            descriptors: trained.descriptors,
            cached,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn tree_shape_follows_the_descriptor_count() {
        // The thesis's 10,000 words: k = 10, L = 4.
        assert_eq!(tree_shape(100_000), (10, 4));
        // 20,000 descriptors → 2,000 words: 4 levels, 7⁴ = 2401 ≥ 2000 > 6⁴.
        assert_eq!(tree_shape(20_000), (7, 4));
        assert_eq!(tree_shape(1_000), (10, 2));
        assert_eq!(tree_shape(0), (2, 1));
        assert_eq!(tree_shape(10_000_000), (10, 6));
        for n in [50, 999, 12_345, 77_777] {
            let (k, l) = tree_shape(n);
            let w = (n / DESCRIPTORS_PER_WORD).max(2);
            assert!(
                k.pow(l as u32) >= w && (k - 1).pow(l as u32) < w,
                "{n}: {k} {l}"
            );
            assert!(MAX_BRANCHING.pow(l as u32 - 1) < w);
        }
    }

    /// Write → read gives the same vocabulary (nodes, weights to the bit, words) and the same
    /// BoW vectors.
    #[test]
    fn dbow2_yaml_round_trip() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let images: Vec<Vec<Descriptor>> = (0..12)
            .map(|_| {
                (0..80)
                    .map(|_| [rng.random(), rng.random(), rng.random(), rng.random()])
                    .collect()
            })
            .collect();
        let voc = Vocabulary::train(&images, 5, 3, 10, 1).unwrap();
        assert!(voc.num_words() > 50);
        let mut text = Vec::new();
        write_dbow2_yaml(&voc, &mut text).unwrap();
        let back = Vocabulary::parse_dbow_yaml(std::str::from_utf8(&text).unwrap()).unwrap();
        assert_eq!(back, voc);
        for img in &images {
            assert_eq!(back.transform(img), voc.transform(img));
        }
        // Through a file, atomically.
        let dir = std::env::temp_dir().join(format!("dwslam-voc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("v.yml");
        save(&voc, &path).unwrap();
        assert_eq!(Vocabulary::load_dbow_yaml(&path).unwrap(), voc);
        let leftovers = std::fs::read_dir(&dir).unwrap().count();
        assert_eq!(leftovers, 1, "no temporary file is left");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The default vocabulary: 22 distinct images, a shape from the descriptor count, the same
    /// vocabulary from two trainings and the shipped one; other ORB parameters train, cache on
    /// the first load and read back on the second, a corrupt cache trained over.
    #[test]
    fn default_vocabulary_trains_reproducibly_and_is_cached() {
        let Some(root) = data::paths::require("slambook2_sample_images")
            .and_then(|_| data::paths::dataset_root())
        else {
            return;
        };
        let orb = crate::place_recognition::OrbConfig::default().params();
        let set = TrainingSet::read(
            &default_training_images(&root).unwrap(),
            TrainingParams::new(orb),
        )
        .unwrap();
        assert_eq!((set.images.len(), set.duplicates.len()), (22, 1));
        assert!(set.duplicates[0].ends_with("rgbd_pair/1.png"));
        let a = train(&set, &|_, _| {}).unwrap();
        let b = train(&set, &|_, _| {}).unwrap();
        assert_eq!(a.vocabulary, b.vocabulary);
        assert_eq!(
            (a.vocabulary.k, a.vocabulary.levels),
            tree_shape(a.descriptors)
        );
        let per_word = a.descriptors as f64 / a.vocabulary.num_words() as f64;
        assert!(
            (5.0..20.0).contains(&per_word),
            "{per_word} descriptors per word"
        );
        assert_eq!(default_vocabulary().unwrap(), a.vocabulary);
        let shipped = load_vocabulary_cached(None, Some(&root), &orb, None).unwrap();
        assert_eq!(shipped.origin, VocabularyOrigin::Shipped);
        let orb = OrbParams {
            num_features: 500,
            ..orb
        };
        let a = train(
            &TrainingSet::read(&set.images, TrainingParams::new(orb)).unwrap(),
            &|_, _| {},
        )
        .unwrap();
        let cache = std::env::temp_dir().join(format!("dwslam-voccache-{}", std::process::id()));
        let load = || load_vocabulary_cached(None, Some(&root), &orb, Some(&cache)).unwrap();
        let first = load();
        let VocabularyOrigin::Trained {
            cached: Ok(path), ..
        } = &first.origin
        else {
            panic!("{:?}", first.origin);
        };
        assert_eq!(*first.vocabulary, a.vocabulary);
        let second = load();
        assert_eq!(second.origin, VocabularyOrigin::Cache(path.clone()));
        assert_eq!(*second.vocabulary, a.vocabulary);
        std::fs::write(path, "vocabulary: {k: 2").unwrap();
        assert!(matches!(
            load().origin,
            VocabularyOrigin::Trained { cached: Ok(_), .. }
        ));
        assert_eq!(load().origin, VocabularyOrigin::Cache(path.clone()));
        std::fs::remove_dir_all(&cache).unwrap();
    }

    #[test]
    fn training_sets_drop_duplicates_and_name_bad_inputs() {
        let dir = std::env::temp_dir().join(format!("dwslam-vocset-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let img = vision::image::GrayImage::from_fn(64, 64, |u, v| ((u * 7 + v * 13) % 256) as u8);
        // Binary PGM (P5), which `vision::image` decodes.
        let write_pgm = |p: &Path, i: &vision::image::GrayImage| {
            let mut bytes = b"P5\n64 64\n255\n".to_vec();
            bytes.extend_from_slice(i.data());
            std::fs::write(p, bytes).unwrap();
        };
        write_pgm(&dir.join("a.pgm"), &img);
        write_pgm(&dir.join("sub/b.pgm"), &img);
        std::fs::write(dir.join("notes.txt"), "x").unwrap();
        let images = collect_images(std::slice::from_ref(&dir)).unwrap();
        assert_eq!(images, vec![dir.join("a.pgm"), dir.join("sub/b.pgm")]);
        let params = TrainingParams::new(OrbParams::default());
        let set = TrainingSet::read(&images, params).unwrap();
        assert_eq!(set.images.len(), 1);
        assert_eq!(set.duplicates, vec![dir.join("sub/b.pgm")]);
        // The key follows the parameters.
        let other = TrainingSet::read(&images, TrainingParams { seed: 1, ..params }).unwrap();
        assert_ne!(set.key, other.key);
        let missing = collect_images(&[dir.join("nope")]).unwrap_err().to_string();
        assert!(missing.contains("nope"), "{missing}");
        std::fs::create_dir_all(dir.join("empty")).unwrap();
        assert!(collect_images(&[dir.join("empty")]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
