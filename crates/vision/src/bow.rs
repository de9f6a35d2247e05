//! Bag of binary words (Gálvez-López & Tardós 2012, "DBoW2") for appearance-based place
//! recognition (thesis §6.4.2, there with SURF; here with 256-bit binary descriptors).
//!
//! - A vocabulary tree with branching factor `k` and depth `L` is trained by hierarchical
//!   k-majority clustering (k-means with Hamming distance and bit-wise majority centres,
//!   k-means++ seeding).
//! - Words (leaves) carry inverse document frequencies `idf_i = ln(N/n_i)` (N training images,
//!   `n_i` of them containing word `i`).
//! - An image becomes the L1-normalised tf-idf vector `v_i = (c_i/n)·idf_i`; two vectors score
//!   `s(v, w) = 1 − ½‖v − w‖₁` (in `[0, 1]`).
//! - A [`Database`] with an inverted file answers queries.
//! - [`Vocabulary::load_dbow_yaml`] reads DBoW2/DBoW3 vocabularies saved by OpenCV's
//!   `FileStorage` (YAML, optionally gzip'd).

use crate::orb::{Descriptor, hamming};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

/// Errors of vocabulary loading and training.
#[derive(Debug, thiserror::Error)]
pub enum BowError {
    /// The file could not be read or un-gzipped.
    #[error("cannot read vocabulary {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The YAML is malformed or lacks the DBoW structure.
    #[error("malformed vocabulary {path}: {message}")]
    Format {
        /// The file.
        path: String,
        /// What was wrong.
        message: String,
    },
    /// Training needs at least one descriptor, `k ≥ 2` and `L ≥ 1`.
    #[error("invalid training input: {0}")]
    Training(String),
}

/// A node of the vocabulary tree.
#[derive(Debug, Clone, PartialEq)]
pub struct VocNode {
    /// Parent node index (the root is its own parent, index 0).
    pub parent: usize,
    /// Child node indices (empty for words).
    pub children: Vec<usize>,
    /// Cluster centre.
    pub descriptor: Descriptor,
    /// Word weight (idf) for leaves; 0 for inner nodes.
    pub weight: f64,
    /// Word id for leaves.
    pub word: Option<usize>,
}

/// A vocabulary tree (node 0 is the root).
#[derive(Debug, Clone, PartialEq)]
pub struct Vocabulary {
    /// Branching factor `k`.
    pub k: usize,
    /// Depth `L`.
    pub levels: usize,
    /// All nodes, root first.
    pub nodes: Vec<VocNode>,
    /// Node index of each word.
    pub words: Vec<usize>,
}

/// A sparse bag-of-words vector: `(word id, value)` sorted by word id, L1-normalised.
pub type BowVector = Vec<(usize, f64)>;

impl Vocabulary {
    /// Number of words.
    pub fn num_words(&self) -> usize {
        self.words.len()
    }

    /// Trains a vocabulary with branching `k` and depth `levels` on the descriptors of a set of
    /// training images (one `Vec` per image), by hierarchical k-majority clustering with
    /// k-means++ seeding (seeded), at most `max_iterations` Lloyd iterations per node; then sets
    /// `idf_i = ln(N/n_i)`.
    pub fn train(
        images: &[Vec<Descriptor>],
        k: usize,
        levels: usize,
        max_iterations: usize,
        seed: u64,
    ) -> Result<Self, BowError> {
        if k < 2 || levels < 1 {
            return Err(BowError::Training(format!("k = {k}, L = {levels}")));
        }
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.is_empty() {
            return Err(BowError::Training("no descriptors".into()));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut voc = Vocabulary {
            k,
            levels,
            nodes: vec![VocNode {
                parent: 0,
                children: Vec::new(),
                descriptor: [0; 4],
                weight: 0.0,
                word: None,
            }],
            words: Vec::new(),
        };
        let idx: Vec<usize> = (0..all.len()).collect();
        voc.grow(0, &all, idx, 1, max_iterations, &mut rng);
        for (i, n) in voc.nodes.iter_mut().enumerate() {
            if n.children.is_empty() && i != 0 {
                n.word = Some(voc.words.len());
                voc.words.push(i);
            }
        }
        if voc.words.is_empty() {
            // A single-descriptor training set: the root's only child is the one word.
            return Err(BowError::Training("training produced no words".into()));
        }
        // idf weights.
        let n_img = images.len() as f64;
        let mut df = vec![0usize; voc.words.len()];
        for img in images {
            let mut seen: Vec<usize> = img.iter().map(|d| voc.word_of(d).0).collect();
            seen.sort_unstable();
            seen.dedup();
            for w in seen {
                df[w] += 1;
            }
        }
        for (w, &n) in voc.words.clone().iter().zip(&df) {
            voc.nodes[*w].weight = if n > 0 { (n_img / n as f64).ln() } else { 0.0 };
        }
        Ok(voc)
    }

    fn grow(
        &mut self,
        node: usize,
        all: &[Descriptor],
        idx: Vec<usize>,
        depth: usize,
        max_it: usize,
        rng: &mut ChaCha8Rng,
    ) {
        let k = self.k;
        let clusters: Vec<(Descriptor, Vec<usize>)> = if idx.len() <= k {
            let mut uniq: Vec<Descriptor> = idx.iter().map(|&i| all[i]).collect();
            uniq.sort_unstable();
            uniq.dedup();
            uniq.into_iter()
                .map(|c| (c, idx.iter().copied().filter(|&i| all[i] == c).collect()))
                .collect()
        } else {
            kmajority(all, &idx, k, max_it, rng)
        };
        for (centre, members) in clusters {
            if members.is_empty() {
                continue;
            }
            let child = self.nodes.len();
            self.nodes.push(VocNode {
                parent: node,
                children: Vec::new(),
                descriptor: centre,
                weight: 0.0,
                word: None,
            });
            self.nodes[node].children.push(child);
            if depth < self.levels && members.len() > 1 {
                self.grow(child, all, members, depth + 1, max_it, rng);
            }
        }
    }

    /// A 64-bit fingerprint of the whole tree (branching, depth, every node's parent,
    /// children, centre, weight and word): the vocabulary's identity, which a map file records
    /// (its keyframes' words and scores mean nothing under another vocabulary). FNV-1a over
    /// 64-bit words: one pass, ~10 ms for a 10⁶-node tree.
    pub fn fingerprint(&self) -> u64 {
        const PRIME: u64 = 0x0000_0100_0000_01b3;
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut mix = |x: u64| h = (h ^ x).wrapping_mul(PRIME);
        mix(self.k as u64);
        mix(self.levels as u64);
        mix(self.nodes.len() as u64);
        for n in &self.nodes {
            mix(n.parent as u64);
            mix(n.children.len() as u64);
            for &c in &n.children {
                mix(c as u64);
            }
            n.descriptor.iter().for_each(|&d| mix(d));
            mix(n.weight.to_bits());
            mix(n.word.map_or(u64::MAX, |w| w as u64));
        }
        mix(self.words.len() as u64);
        h
    }

    /// Descends the tree to the word of a descriptor (nearest child by Hamming distance at each
    /// level). Returns `(word id, node index)`.
    pub fn word_of(&self, d: &Descriptor) -> (usize, usize) {
        let mut n = 0usize;
        while !self.nodes[n].children.is_empty() {
            let mut best = (u32::MAX, 0usize);
            for &c in &self.nodes[n].children {
                let dist = hamming(d, &self.nodes[c].descriptor);
                if dist < best.0 {
                    best = (dist, c);
                }
            }
            n = best.1;
        }
        (self.nodes[n].word.unwrap_or(0), n)
    }

    /// The L1-normalised tf-idf vector of an image's descriptors.
    pub fn transform(&self, descriptors: &[Descriptor]) -> BowVector {
        let mut acc: HashMap<usize, f64> = HashMap::new();
        let n = descriptors.len().max(1) as f64;
        for d in descriptors {
            let (w, node) = self.word_of(d);
            let weight = self.nodes[node].weight;
            if weight > 0.0 {
                *acc.entry(w).or_default() += weight / n;
            }
        }
        let mut v: BowVector = acc.into_iter().collect();
        v.sort_unstable_by_key(|x| x.0);
        let norm: f64 = v.iter().map(|x| x.1.abs()).sum();
        if norm > 0.0 {
            v.iter_mut().for_each(|x| x.1 /= norm);
        }
        v
    }

    /// Reads a DBoW2/DBoW3 vocabulary written by OpenCV's `FileStorage` (YAML, gzip'd if the
    /// name ends in `.gz`): `vocabulary: {k, L, scoringType, weightingType, nodes: [{nodeId,
    /// parentId, weight, descriptor}], words: [{wordId, nodeId}]}`. Descriptor strings are 32
    /// byte values, optionally preceded by the OpenCV type and column count (DBoW3: `"0 32 …"`).
    /// The `%YAML:1.0` directive is stripped and OpenCV's `key:value` flow pairs are spaced
    /// before parsing with `serde-saphyr`.
    pub fn load_dbow_yaml(path: impl AsRef<Path>) -> Result<Self, BowError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let io = |e| BowError::Io {
            path: name.clone(),
            source: e,
        };
        let raw = std::fs::read(path).map_err(io)?;
        let text = if name.ends_with(".gz") {
            let mut s = String::new();
            flate2::read::GzDecoder::new(&raw[..])
                .read_to_string(&mut s)
                .map_err(io)?;
            s
        } else {
            String::from_utf8(raw).map_err(|e| BowError::Format {
                path: name.clone(),
                message: e.to_string(),
            })?
        };
        Self::parse_dbow_yaml(&text).map_err(|message| BowError::Format {
            path: name.clone(),
            message,
        })
    }

    /// Parses the text of a DBoW YAML vocabulary (see [`load_dbow_yaml`](Self::load_dbow_yaml)).
    pub fn parse_dbow_yaml(text: &str) -> Result<Self, String> {
        #[derive(serde::Deserialize)]
        struct File {
            vocabulary: Voc,
        }
        #[derive(serde::Deserialize)]
        struct Voc {
            k: usize,
            #[serde(rename = "L")]
            l: usize,
            nodes: Vec<Node>,
            words: Vec<Word>,
        }
        #[derive(serde::Deserialize)]
        struct Node {
            #[serde(rename = "nodeId")]
            node_id: usize,
            #[serde(rename = "parentId")]
            parent_id: usize,
            weight: f64,
            descriptor: String,
        }
        #[derive(serde::Deserialize)]
        struct Word {
            #[serde(rename = "wordId")]
            word_id: usize,
            #[serde(rename = "nodeId")]
            node_id: usize,
        }
        let body = text
            .strip_prefix("%YAML:1.0")
            .or_else(|| text.strip_prefix("%YAML 1.0"))
            .unwrap_or(text);
        let fixed = space_flow_pairs(body);
        let f: File = serde_saphyr::from_str(&fixed).map_err(|e| e.to_string())?;
        let v = f.vocabulary;
        let n = v.nodes.iter().map(|x| x.node_id).max().unwrap_or(0) + 1;
        let mut nodes = vec![
            VocNode {
                parent: 0,
                children: Vec::new(),
                descriptor: [0; 4],
                weight: 0.0,
                word: None
            };
            n
        ];
        for node in &v.nodes {
            if node.parent_id >= n {
                return Err(format!(
                    "node {} has unknown parent {}",
                    node.node_id, node.parent_id
                ));
            }
            let nums: Result<Vec<u8>, _> = node
                .descriptor
                .split_whitespace()
                .map(|s| s.parse::<u8>())
                .collect();
            let nums = nums.map_err(|e| format!("node {}: bad descriptor: {e}", node.node_id))?;
            let bytes = match nums.len() {
                32 => &nums[..],
                34 if nums[0] == 0 && nums[1] == 32 => &nums[2..],
                l => {
                    return Err(format!(
                        "node {}: descriptor has {l} values, expected 32 bytes",
                        node.node_id
                    ));
                }
            };
            let mut d = [0u64; 4];
            for (i, b) in bytes.iter().enumerate() {
                d[i / 8] |= (*b as u64) << ((i % 8) * 8);
            }
            let nd = &mut nodes[node.node_id];
            nd.parent = node.parent_id;
            nd.descriptor = d;
            nd.weight = node.weight;
        }
        for node in &v.nodes {
            nodes[node.parent_id].children.push(node.node_id);
        }
        let mut words = vec![0usize; v.words.len()];
        for w in &v.words {
            if w.word_id >= words.len() || w.node_id >= n {
                return Err(format!(
                    "word {} refers to node {} out of range",
                    w.word_id, w.node_id
                ));
            }
            words[w.word_id] = w.node_id;
            nodes[w.node_id].word = Some(w.word_id);
        }
        Ok(Vocabulary {
            k: v.k,
            levels: v.l,
            nodes,
            words,
        })
    }
}

/// Inserts a space after `key:` where OpenCV writes flow pairs without one (`{ nodeId:1, … }`),
/// which YAML would otherwise read as a single plain scalar. Text inside double quotes is left
/// alone.
fn space_flow_pairs(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + s.len() / 8);
    let mut in_quote = false;
    let mut prev_alpha = false;
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        out.push(c);
        if c == '"' {
            in_quote = !in_quote;
        }
        if !in_quote && c == ':' && prev_alpha && chars.peek().is_some_and(|n| !n.is_whitespace()) {
            out.push(' ');
        }
        prev_alpha = c.is_ascii_alphanumeric() || c == '_';
    }
    out
}

/// k-majority clustering of `all[idx]`: k-means++ seeding, assignment to the nearest centre by
/// Hamming distance, centres updated to the bit-wise majority of their members.
fn kmajority(
    all: &[Descriptor],
    idx: &[usize],
    k: usize,
    max_it: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<(Descriptor, Vec<usize>)> {
    // k-means++ seeding with D² sampling.
    let mut centres: Vec<Descriptor> = vec![all[idx[rng.random_range(0..idx.len())]]];
    let mut dmin: Vec<f64> = idx
        .iter()
        .map(|&i| hamming(&all[i], &centres[0]) as f64)
        .collect();
    while centres.len() < k {
        let total: f64 = dmin.iter().map(|d| d * d).sum();
        if total <= 0.0 {
            break;
        }
        let mut r = rng.random::<f64>() * total;
        let mut pick = idx.len() - 1;
        for (j, d) in dmin.iter().enumerate() {
            r -= d * d;
            if r <= 0.0 {
                pick = j;
                break;
            }
        }
        let c = all[idx[pick]];
        centres.push(c);
        for (j, &i) in idx.iter().enumerate() {
            dmin[j] = dmin[j].min(hamming(&all[i], &c) as f64);
        }
    }
    let mut assign = vec![usize::MAX; idx.len()];
    for _ in 0..max_it.max(1) {
        let mut changed = false;
        for (j, &i) in idx.iter().enumerate() {
            let mut best = (u32::MAX, 0);
            for (c, cd) in centres.iter().enumerate() {
                let d = hamming(&all[i], cd);
                if d < best.0 {
                    best = (d, c);
                }
            }
            if assign[j] != best.1 {
                assign[j] = best.1;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        // Majority update.
        let mut counts = vec![[0u32; 256]; centres.len()];
        let mut sizes = vec![0u32; centres.len()];
        for (j, &i) in idx.iter().enumerate() {
            let c = assign[j];
            sizes[c] += 1;
            for (b, cnt) in counts[c].iter_mut().enumerate() {
                *cnt += ((all[i][b >> 6] >> (b & 63)) & 1) as u32;
            }
        }
        for (c, centre) in centres.iter_mut().enumerate() {
            if sizes[c] == 0 {
                continue;
            }
            let mut d = [0u64; 4];
            for b in 0..256 {
                if 2 * counts[c][b] > sizes[c] {
                    d[b >> 6] |= 1u64 << (b & 63);
                }
            }
            *centre = d;
        }
    }
    let mut out: Vec<(Descriptor, Vec<usize>)> =
        centres.into_iter().map(|c| (c, Vec::new())).collect();
    for (j, &i) in idx.iter().enumerate() {
        out[assign[j]].1.push(i);
    }
    out
}

/// The L1 similarity `s(v, w) = 1 − ½‖v − w‖₁` of two L1-normalised BoW vectors, computed over
/// common words as `½ Σ (|v_i| + |w_i| − |v_i − w_i|)`.
pub fn score_l1(a: &BowVector, b: &BowVector) -> f64 {
    let (mut i, mut j, mut s) = (0, 0, 0.0);
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                let (x, y) = (a[i].1, b[j].1);
                s += x.abs() + y.abs() - (x - y).abs();
                i += 1;
                j += 1;
            }
        }
    }
    0.5 * s
}

/// An image database with an inverted file (word → images containing it).
#[derive(Debug, Clone, Default)]
pub struct Database {
    vectors: Vec<BowVector>,
    inverted: HashMap<usize, Vec<(usize, f64)>>,
}

impl Database {
    /// An empty database.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds an image's BoW vector; returns its entry id (0, 1, …).
    pub fn add(&mut self, v: BowVector) -> usize {
        let id = self.vectors.len();
        for &(w, x) in &v {
            self.inverted.entry(w).or_default().push((id, x));
        }
        self.vectors.push(v);
        id
    }

    /// Removes entry `id` from the inverted file (it is never returned again; ids stay as
    /// they are). Nothing happens for an unknown or removed entry.
    pub fn remove(&mut self, id: usize) {
        let Some(v) = self.vectors.get_mut(id) else {
            return;
        };
        for (w, _) in std::mem::take(v) {
            if let Some(list) = self.inverted.get_mut(&w) {
                list.retain(|&(e, _)| e != id);
                if list.is_empty() {
                    self.inverted.remove(&w);
                }
            }
        }
    }

    /// Number of entries ever added (removed ones included).
    pub fn len(&self) -> usize {
        self.vectors.len()
    }

    /// True if empty.
    pub fn is_empty(&self) -> bool {
        self.vectors.is_empty()
    }

    /// The `max_results` best entries for a query vector by [`score_l1`], best first, as
    /// `(entry id, score)`; only entries sharing a word with the query are scored.
    pub fn query(&self, v: &BowVector, max_results: usize) -> Vec<(usize, f64)> {
        let mut acc: HashMap<usize, f64> = HashMap::new();
        for &(w, x) in v {
            if let Some(list) = self.inverted.get(&w) {
                for &(id, y) in list {
                    *acc.entry(id).or_default() += x.abs() + y.abs() - (x - y).abs();
                }
            }
        }
        let mut r: Vec<(usize, f64)> = acc.into_iter().map(|(id, s)| (id, 0.5 * s)).collect();
        r.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        r.truncate(max_results);
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rand_desc(rng: &mut ChaCha8Rng) -> Descriptor {
        [rng.random(), rng.random(), rng.random(), rng.random()]
    }

    fn flip(d: &Descriptor, bits: usize, rng: &mut ChaCha8Rng) -> Descriptor {
        let mut o = *d;
        for _ in 0..bits {
            let b = rng.random_range(0..256);
            o[b >> 6] ^= 1 << (b & 63);
        }
        o
    }

    #[test]
    fn train_query_finds_the_right_image() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // 20 "places", each with 60 characteristic descriptors.
        let places: Vec<Vec<Descriptor>> = (0..20)
            .map(|_| (0..60).map(|_| rand_desc(&mut rng)).collect())
            .collect();
        let voc = Vocabulary::train(&places, 6, 3, 10, 7).unwrap();
        assert!(voc.num_words() > 50);
        let mut db = Database::new();
        for p in &places {
            db.add(voc.transform(p));
        }
        for (i, p) in places.iter().enumerate() {
            // A noisy re-observation of 40 of the place's descriptors.
            let q: Vec<Descriptor> = p.iter().take(40).map(|d| flip(d, 10, &mut rng)).collect();
            let r = db.query(&voc.transform(&q), 3);
            assert_eq!(r[0].0, i);
        }
        let v = voc.transform(&places[0]);
        assert!((score_l1(&v, &v) - 1.0).abs() < 1e-9);
        // A removed entry is never returned again; the others keep their ids.
        db.remove(0);
        db.remove(0);
        db.remove(99);
        let r = db.query(&v, 20);
        assert!(r.iter().all(|&(e, _)| e != 0), "{r:?}");
        let q: Vec<Descriptor> = places[3].iter().take(40).copied().collect();
        assert_eq!(db.query(&voc.transform(&q), 1)[0].0, 3);
        assert!(Vocabulary::train(&[], 5, 2, 5, 0).is_err());
        assert!(Vocabulary::train(&places, 1, 2, 5, 0).is_err());
    }

    #[test]
    fn parses_opencv_flow_pairs() {
        let text = "%YAML:1.0\n---\nvocabulary:\n   k: 2\n   L: 1\n   scoringType: 0\n   weightingType: 0\n   nodes:\n      - { nodeId:1, parentId:0, weight:0.5,\n          descriptor:\"0 32 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 255 \" }\n      - { nodeId:2, parentId:0, weight:0.,\n          descriptor:\"2 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 \" }\n   words:\n      - { wordId:0, nodeId:1 }\n      - { wordId:1, nodeId:2 }\n";
        let v = Vocabulary::parse_dbow_yaml(text).unwrap();
        assert_eq!(v.num_words(), 2);
        assert_eq!(v.nodes[1].descriptor[0], 1);
        assert_eq!(v.nodes[1].descriptor[3], 255u64 << 56);
        assert_eq!(v.nodes[2].descriptor[0], 2);
        assert_eq!(v.nodes[0].children, vec![1, 2]);
        assert!(Vocabulary::parse_dbow_yaml("vocabulary: {k: 2}").is_err());
        assert!(Vocabulary::load_dbow_yaml("/nonexistent.yml.gz").is_err());
    }
}
