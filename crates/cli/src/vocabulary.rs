//! `dwslam vocabulary`: trains the binary bag-of-words vocabulary of place recognition (thesis
//! §6.4.2) on images disjoint from the test sequences and writes it as a DBoW2 YAML file
//! (`system::vocabulary`). Without images it trains the default vocabulary
//! the live system would train itself, on the shared images that belong to no test sequence.

use anyhow::{Context, Result, bail};
use clap::Args;
use std::path::PathBuf;
use system::PlaceRecognitionConfig;
use system::vocabulary::{
    DEFAULT_TRAINING_SET, TrainingParams, TrainingSet, collect_images, default_training_images,
    save, train,
};

/// Options of `dwslam vocabulary`.
#[derive(Args, Debug)]
pub struct VocabularyArgs {
    /// Training images and folders of images (searched recursively). Default: the shared
    /// images of no test sequence (slambook2 samples, Middlebury stereo, the TUM fr1_xyz
    /// fragment) under $DWSLAM_DATA.
    pub images: Vec<PathBuf>,
    /// The vocabulary file to write (DBoW2 YAML).
    #[arg(long, default_value = "out/vocabulary.yml")]
    pub out: PathBuf,
    /// Branching factor k (with --levels; default: chosen from the number of training
    /// descriptors, about ten per word).
    #[arg(long, requires = "levels")]
    pub k: Option<usize>,
    /// Depth L of the tree (with --k).
    #[arg(long, requires = "k")]
    pub levels: Option<usize>,
}

pub fn run(args: VocabularyArgs) -> Result<()> {
    // Every argument is checked before any work.
    crate::args::output_file(&args.out, "--out")?;
    if let (Some(k), Some(l)) = (args.k, args.levels) {
        if k < 2 {
            bail!("--k must be at least 2 (got {k})");
        }
        if !(1..=12).contains(&l) {
            bail!("--levels must lie in 1..=12 (got {l})");
        }
    }
    let images = if args.images.is_empty() {
        let root = data::paths::dataset_root().with_context(|| {
            format!(
                "no images given and the shared data folder (${}) was not found: it holds the \
                 default training images {}",
                data::paths::DATA_ENV,
                DEFAULT_TRAINING_SET.join(", ")
            )
        })?;
        default_training_images(&root)?
    } else {
        for p in &args.images {
            if p.is_dir() {
                crate::args::input_dir(p, "image folder")?;
            } else {
                crate::args::input_file(p, "image")?;
            }
        }
        collect_images(&args.images)?
    };
    let orb = PlaceRecognitionConfig::default().orb.params();
    let params = TrainingParams {
        shape: args.k.zip(args.levels),
        ..TrainingParams::new(orb)
    };
    let set = TrainingSet::read(&images, params)?;
    println!(
        "training on {} images ({} duplicates left out), {} ORB features per image",
        set.images.len(),
        set.duplicates.len(),
        orb.num_features
    );
    let bar = crate::experiment::progress(set.images.len(), "extracting ORB features");
    let trained = train(&set, &|done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    let voc = &trained.vocabulary;
    println!(
        "{} descriptors → k = {}, L = {}: {} words ({:.1} descriptors per word); extraction \
         {:.2} s, clustering {:.2} s",
        trained.descriptors,
        voc.k,
        voc.levels,
        voc.num_words(),
        trained.descriptors as f64 / voc.num_words().max(1) as f64,
        trained.extraction_seconds,
        trained.clustering_seconds
    );
    save(voc, &args.out)?;
    println!("wrote {}", args.out.display());
    Ok(())
}
