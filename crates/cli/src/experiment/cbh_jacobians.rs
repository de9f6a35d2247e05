//! Thesis Table 5.1: accuracy of the first-, second- and third-order Campbell-Baker-Hausdorff
//! approximations of the pose-graph Jacobian `J_A^B = ∂ log(A·exp(ε)·B)^∨/∂ε` (thesis §5.4,
//! eq. 5.20–5.22).
//!
//! As in the thesis, `A = exp(a)` and `B = exp(b)` with `bᵢ = −aᵢ + 𝒩(0, σ²)`, so `A·B` is
//! near the identity and `d = log(A·B)` has a size of order `σ`. The thesis does not say how
//! `a` is drawn; we draw its components from `𝒩(0, 1)` (rotation vectors resampled until
//! `‖ω‖ < π`), which reproduces the thesis's `‖d‖` column. Each cell averages over the
//! samples the Frobenius norm of `J_num − J_k`, `J_num` being the Richardson-refined central
//! difference of [`lie::numeric::d_log_left`].

use lie::{LieGroup, LogJacobian, Se3, Sim3, So3};
use nalgebra::SVector;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

/// Thesis Table 5.1: `(group, σ, ‖d‖, ‖J_num − J₁‖, ‖J_num − J₂‖, ‖J_num − J₃‖)`.
pub const THESIS_TABLE: [(&str, f64, [f64; 4]); 9] = [
    (
        "SO(3)",
        0.0005,
        [8.0622e-4, 5.7008e-4, 8.7931e-8, 1.2267e-10],
    ),
    ("SO(3)", 0.015, [2.5554e-2, 1.8070e-2, 8.5531e-5, 7.8969e-9]),
    ("SO(3)", 0.5, [7.7543e-1, 5.5622e-1, 8.6935e-2, 1.9021e-3]),
    (
        "SE(3)",
        0.0005,
        [1.1390e-3, 1.0167e-3, 1.5861e-7, 3.0536e-10],
    ),
    ("SE(3)", 0.015, [3.6641e-2, 3.2604e-2, 1.6346e-4, 6.3008e-9]),
    ("SE(3)", 0.5, [1.1857, 1.0576, 1.6580e-1, 3.1948e-3]),
    (
        "Sim(3)",
        0.0005,
        [1.5068e-3, 1.7052e-3, 2.9849e-7, 4.7997e-10],
    ),
    (
        "Sim(3)",
        0.015,
        [4.3008e-2, 4.9284e-2, 2.4271e-4, 1.1705e-8],
    ),
    ("Sim(3)", 0.5, [1.5567, 1.7407, 2.9783e-1, 6.8600e-3]),
];

/// How far from the thesis a cell may be: a factor of 5, except where the thesis's value is
/// below `1e-8`, which is the precision of its numeric Jacobian: there ours must be below
/// `1e-7` (issue 2's acceptance rule).
pub fn cell_agrees(ours: f64, thesis: f64) -> bool {
    if thesis < 1e-8 {
        ours < 1e-7
    } else {
        ours <= 5.0 * thesis && ours >= thesis / 5.0
    }
}

/// One row of the table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// `SO(3)`, `SE(3)` or `Sim(3)`.
    pub group: String,
    /// The noise level σ.
    pub sigma: f64,
    /// Mean `‖d‖₂`, `d = log(A·B)`.
    pub d_norm: f64,
    /// Mean `‖J_num − J₁‖_F`.
    pub err_j1: f64,
    /// Mean `‖J_num − J₂‖_F`.
    pub err_j2: f64,
    /// Mean `‖J_num − J₃‖_F`.
    pub err_j3: f64,
    /// Mean `‖J_num − J_exact‖_F`: the precision of the numeric reference itself.
    pub err_exact: f64,
    /// The thesis's `[‖d‖, err₁, err₂, err₃]` for this cell.
    pub thesis: [f64; 4],
}

impl Row {
    /// Whether all four of our numbers agree with the thesis's (see [`cell_agrees`]).
    pub fn agrees_with_thesis(&self) -> bool {
        [self.d_norm, self.err_j1, self.err_j2, self.err_j3]
            .iter()
            .zip(self.thesis)
            .all(|(&ours, thesis)| cell_agrees(ours, thesis))
    }
}

/// A random tangent with `𝒩(0, 1)` components whose rotation part (indices `rot`) has norm
/// below π, so that `a` is a principal logarithm.
fn random_tangent<const D: usize>(
    rng: &mut ChaCha8Rng,
    rot: std::ops::Range<usize>,
) -> SVector<f64, D> {
    let normal = Normal::new(0.0, 1.0).expect("unit normal");
    loop {
        let a = SVector::<f64, D>::from_fn(|_, _| normal.sample(rng));
        if a.rows(rot.start, rot.len()).norm() < std::f64::consts::PI {
            return a;
        }
    }
}

fn cell<G: LieGroup<D>, const D: usize>(
    rng: &mut ChaCha8Rng,
    rot: std::ops::Range<usize>,
    sigma: f64,
    samples: usize,
) -> [f64; 5] {
    let noise = Normal::new(0.0, sigma).expect("σ > 0");
    let mut sums = [0.0; 5];
    for _ in 0..samples {
        let a = random_tangent::<D>(rng, rot.clone());
        let b = -a + SVector::<f64, D>::from_fn(|_, _| noise.sample(rng));
        let (ga, gb) = (G::exp(&a), G::exp(&b));
        let numeric = lie::numeric::d_log_left(&ga, &gb);
        sums[0] += ga.compose(&gb).log().norm();
        for (k, method) in [
            LogJacobian::Cbh1,
            LogJacobian::Cbh2,
            LogJacobian::Cbh3,
            LogJacobian::Exact,
        ]
        .into_iter()
        .enumerate()
        {
            sums[k + 1] += (numeric - G::d_log_left(&ga, &gb, method)).norm();
        }
    }
    sums.map(|s| s / samples as f64)
}

/// Computes the whole table: 3 groups × 3 noise levels, `samples` draws per cell, from `seed`.
pub fn table(seed: u64, samples: usize) -> Vec<Row> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut rows = Vec::new();
    for (group, sigma, thesis) in THESIS_TABLE {
        let m = match group {
            "SO(3)" => cell::<So3, 3>(&mut rng, 0..3, sigma, samples),
            "SE(3)" => cell::<Se3, 6>(&mut rng, 3..6, sigma, samples),
            _ => cell::<Sim3, 7>(&mut rng, 3..6, sigma, samples),
        };
        rows.push(Row {
            group: group.to_string(),
            sigma,
            d_norm: m[0],
            err_j1: m[1],
            err_j2: m[2],
            err_j3: m[3],
            err_exact: m[4],
            thesis,
        });
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn higher_cbh_orders_are_more_accurate_and_match_the_thesis() {
        let rows = table(2012, 100);
        for row in &rows {
            assert!(
                row.err_j3 < row.err_j2 && row.err_j2 < row.err_j1,
                "{} σ={}: J3 {:e}, J2 {:e}, J1 {:e}",
                row.group,
                row.sigma,
                row.err_j3,
                row.err_j2,
                row.err_j1
            );
            assert!(
                row.err_exact < 1e-9,
                "exact log Jacobian off by {:e}",
                row.err_exact
            );
            assert!(row.agrees_with_thesis(), "{row:?}");
        }
    }

    #[test]
    fn same_seed_same_table() {
        let a = table(5, 10);
        let b = table(5, 10);
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(
                (x.d_norm, x.err_j1, x.err_j2, x.err_j3),
                (y.d_norm, y.err_j1, y.err_j2, y.err_j3)
            );
        }
    }

    #[test]
    fn the_agreement_rule() {
        assert!(cell_agrees(4.9e-3, 1e-3));
        assert!(!cell_agrees(5.1e-3, 1e-3));
        assert!(!cell_agrees(1.9e-4, 1e-3));
        assert!(cell_agrees(9e-8, 1.2e-10));
        assert!(!cell_agrees(2e-7, 1.2e-10));
    }
}
