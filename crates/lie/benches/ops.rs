//! Micro-benchmark of the group operations: nanoseconds per operation, median of repeated
//! runs over 1024 different inputs, next to nalgebra's `Isometry3` / `Similarity3` /
//! `UnitQuaternion` (the closest operations a Rust user would otherwise reach for) measured in
//! the same run. Run with `cargo bench -p lie --bench ops` or `bench/lie/run.sh`.

use lie::{LieGroup, Se3, Sim3};
use nalgebra::{Isometry3, SVector, Similarity3, Translation3, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::time::Instant;

const N: usize = 1024;

/// One table row: our operation, our ns/op, and the nalgebra peer with its ns/op.
type Row = (&'static str, f64, Option<(&'static str, f64)>);
const REPEATS: usize = 31;

/// Median nanoseconds per call of `f(i)` for `i` in `0..N`, over `REPEATS` runs of `rounds`
/// passes.
fn time_ns(rounds: usize, mut f: impl FnMut(usize)) -> f64 {
    let mut samples = Vec::with_capacity(REPEATS);
    for _ in 0..REPEATS {
        let start = Instant::now();
        for _ in 0..rounds {
            for i in 0..N {
                f(i);
            }
        }
        samples.push(start.elapsed().as_nanos() as f64 / (rounds * N) as f64);
    }
    samples.sort_by(|a, b| a.partial_cmp(b).unwrap());
    samples[REPEATS / 2]
}

fn main() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut r = |s: f64| rng.random_range(-s..s);
    let t6: Vec<Vector6<f64>> = (0..N).map(|_| Vector6::from_fn(|_, _| r(1.5))).collect();
    let t7: Vec<SVector<f64, 7>> = (0..N)
        .map(|_| SVector::<f64, 7>::from_fn(|_, _| r(1.5)))
        .collect();
    let points: Vec<Vector3<f64>> = (0..N).map(|_| Vector3::from_fn(|_, _| r(10.0))).collect();
    let se3: Vec<Se3> = t6.iter().map(Se3::exp).collect();
    let sim3: Vec<Sim3> = t7.iter().map(Sim3::exp).collect();
    let iso: Vec<Isometry3<f64>> = se3.iter().map(|t| t.to_isometry()).collect();
    let sim_na: Vec<Similarity3<f64>> = sim3
        .iter()
        .map(|s| {
            Similarity3::from_parts(
                Translation3::from(*s.translation()),
                *s.rotation().unit_quaternion(),
                s.scale(),
            )
        })
        .collect();
    let omegas: Vec<Vector3<f64>> = t6.iter().map(|t| Vector3::new(t[3], t[4], t[5])).collect();
    let quats: Vec<UnitQuaternion<f64>> = omegas
        .iter()
        .map(|w| UnitQuaternion::from_scaled_axis(*w))
        .collect();
    let rounds = 200;

    let rows: Vec<Row> = vec![
        (
            "SE3 exp",
            time_ns(rounds, |i| {
                black_box(Se3::exp(black_box(&t6[i])));
            }),
            Some((
                "UnitQuaternion::from_scaled_axis (rotation only)",
                time_ns(rounds, |i| {
                    black_box(UnitQuaternion::from_scaled_axis(black_box(omegas[i])));
                }),
            )),
        ),
        (
            "SE3 log",
            time_ns(rounds, |i| {
                black_box(black_box(&se3[i]).log());
            }),
            Some((
                "UnitQuaternion::scaled_axis (rotation only)",
                time_ns(rounds, |i| {
                    black_box(black_box(&quats[i]).scaled_axis());
                }),
            )),
        ),
        (
            "SE3 compose",
            time_ns(rounds, |i| {
                black_box(black_box(&se3[i]).compose(black_box(&se3[(i + 1) % N])));
            }),
            Some((
                "Isometry3 * Isometry3",
                time_ns(rounds, |i| {
                    black_box(black_box(iso[i]) * black_box(iso[(i + 1) % N]));
                }),
            )),
        ),
        (
            "SE3 inverse",
            time_ns(rounds, |i| {
                black_box(black_box(&se3[i]).inverse());
            }),
            Some((
                "Isometry3::inverse",
                time_ns(rounds, |i| {
                    black_box(black_box(iso[i]).inverse());
                }),
            )),
        ),
        (
            "SE3 act",
            time_ns(rounds, |i| {
                black_box(black_box(&se3[i]).act(black_box(&points[i])));
            }),
            Some((
                "Isometry3 * Point3",
                time_ns(rounds, |i| {
                    black_box(black_box(iso[i]).transform_point(&black_box(points[i]).into()));
                }),
            )),
        ),
        (
            "Sim3 exp",
            time_ns(rounds, |i| {
                black_box(Sim3::exp(black_box(&t7[i])));
            }),
            None,
        ),
        (
            "Sim3 log",
            time_ns(rounds, |i| {
                black_box(black_box(&sim3[i]).log());
            }),
            None,
        ),
        (
            "Sim3 compose",
            time_ns(rounds, |i| {
                black_box(black_box(&sim3[i]).compose(black_box(&sim3[(i + 1) % N])));
            }),
            Some((
                "Similarity3 * Similarity3",
                time_ns(rounds, |i| {
                    black_box(black_box(sim_na[i]) * black_box(sim_na[(i + 1) % N]));
                }),
            )),
        ),
        (
            "Sim3 act",
            time_ns(rounds, |i| {
                black_box(black_box(&sim3[i]).act(black_box(&points[i])));
            }),
            Some((
                "Similarity3 * Point3",
                time_ns(rounds, |i| {
                    black_box(black_box(sim_na[i]).transform_point(&black_box(points[i]).into()));
                }),
            )),
        ),
        (
            "SE3 d_log_left exact",
            time_ns(rounds / 10, |i| {
                black_box(Se3::d_log_left(
                    black_box(&se3[i]),
                    black_box(&se3[(i + 1) % N]),
                    lie::LogJacobian::Exact,
                ));
            }),
            None,
        ),
        (
            "SE3 d_log_left cbh2",
            time_ns(rounds / 10, |i| {
                black_box(Se3::d_log_left(
                    black_box(&se3[i]),
                    black_box(&se3[(i + 1) % N]),
                    lie::LogJacobian::Cbh2,
                ));
            }),
            None,
        ),
        (
            "Sim3 d_log_left exact",
            time_ns(rounds / 10, |i| {
                black_box(Sim3::d_log_left(
                    black_box(&sim3[i]),
                    black_box(&sim3[(i + 1) % N]),
                    lie::LogJacobian::Exact,
                ));
            }),
            None,
        ),
        (
            "Sim3 d_log_left cbh2",
            time_ns(rounds / 10, |i| {
                black_box(Sim3::d_log_left(
                    black_box(&sim3[i]),
                    black_box(&sim3[(i + 1) % N]),
                    lie::LogJacobian::Cbh2,
                ));
            }),
            None,
        ),
    ];

    println!("| operation | dwslam ns/op | nalgebra peer | peer ns/op | ratio dwslam/peer |");
    println!("|---|---:|---|---:|---:|");
    for (name, ours, peer) in rows {
        match peer {
            Some((peer_name, peer_ns)) => {
                println!(
                    "| {name} | {ours:.1} | {peer_name} | {peer_ns:.1} | {:.2} |",
                    ours / peer_ns
                )
            }
            None => println!("| {name} | {ours:.1} | — | — | — |"),
        }
    }
}
