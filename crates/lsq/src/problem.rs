//! A least-squares problem: variables, factors, and the sparse structure of its normal
//! equations.

use crate::block::{BlockSymmetric, DisjointMut};
use crate::factor::{Factor, Information, InformationError, Jacobians, MAX_ARITY, Whitening};
use crate::kernels;
use crate::manifold::Manifold;
use crate::robust::RobustKernel;
use crate::values::{Values, Var, VarKey};
use rayon::prelude::*;
use std::collections::HashSet;

/// Handle of a factor in a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FactorId(pub usize);

/// Why a factor or variable setting was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProblemError {
    /// The factor refers to a variable this problem does not hold.
    #[error("factor refers to variable {0:?}, which is not in the problem")]
    UnknownVariable(VarKey),
    /// The factor connects more variables than supported.
    #[error("factor connects {0} variables; at most {MAX_ARITY} are supported")]
    TooManyVariables(usize),
    /// The factor connects no variable.
    #[error("factor connects no variable")]
    NoVariables,
    /// The factor connects the same variable twice.
    #[error("factor connects variable {0:?} twice")]
    DuplicateVariable(VarKey),
    /// The residual has dimension zero.
    #[error("factor has a residual of dimension 0")]
    EmptyResidual,
    /// The information matrix is invalid.
    #[error(transparent)]
    Information(#[from] InformationError),
    /// The robust kernel's width is not positive and finite.
    #[error("robust kernel {0:?} has an invalid width")]
    InvalidKernel(RobustKernel),
    /// A kind marked for elimination (Schur complement) is not block-diagonal in the Hessian.
    #[error(
        "variables of kind {kind} cannot be eliminated: factor {factor} connects two of them, so their Hessian block is not block-diagonal"
    )]
    NotBlockDiagonal {
        /// The manifold name of the kind.
        kind: &'static str,
        /// The offending factor.
        factor: usize,
    },
}

pub(crate) const NONE: u32 = u32::MAX;

pub(crate) struct FactorRecord {
    pub(crate) factor: Box<dyn Factor>,
    pub(crate) vars: [VarKey; MAX_ARITY],
    pub(crate) arity: usize,
    pub(crate) dim: usize,
    pub(crate) whitening: Whitening,
    pub(crate) kernel: Option<RobustKernel>,
}

/// One contribution `J̃_{f,a}ᵀ·J̃_{f,b}` to a Hessian block: where the two Jacobian blocks
/// start in the Jacobian buffer, and the factor's residual size.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Contribution {
    pub(crate) ja: usize,
    pub(crate) jb: usize,
    pub(crate) rows: u32,
}

/// One contribution `J̃_{f,a}ᵀ·r̃_f` to a gradient block.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GradientContribution {
    pub(crate) j: usize,
    pub(crate) r: usize,
    pub(crate) rows: u32,
}

/// The ordering of the free variables and the sparsity of the normal equations, computed
/// once per problem structure and reused across iterations.
pub(crate) struct Structure {
    /// Block index of each variable, per kind (`NONE` when fixed or unused).
    pub(crate) block_of: Vec<Vec<u32>>,
    /// Variable of each block.
    pub(crate) block_keys: Vec<VarKey>,
    /// Blocks `0..num_reduced` are kept; `num_reduced..` are eliminated (Schur complement).
    pub(crate) num_reduced: usize,
    /// Per factor, the block of each of its variables (`NONE` when fixed).
    pub(crate) factor_blocks: Vec<[u32; MAX_ARITY]>,
    /// Per factor, the offset of each variable's Jacobian block within the factor's region.
    pub(crate) jacobian_block_offsets: Vec<[u32; MAX_ARITY]>,
    /// Start of each factor's residual (`len = factors + 1`).
    pub(crate) residual_offsets: Vec<usize>,
    /// Start of each factor's Jacobian region (`len = factors + 1`).
    pub(crate) jacobian_offsets: Vec<usize>,
    /// The Hessian `H = J̃ᵀJ̃` (values are overwritten at each linearisation).
    pub(crate) hessian: BlockSymmetric,
    /// Contributions to each stored Hessian block (`h_contrib_ptr` has `blocks + 1` entries).
    pub(crate) h_contrib_ptr: Vec<usize>,
    pub(crate) h_contrib: Vec<Contribution>,
    /// Contributions `(factor, variable slot)` to each gradient block.
    pub(crate) g_contrib_ptr: Vec<usize>,
    pub(crate) g_contrib: Vec<GradientContribution>,
}

/// Per-structure buffers, allocated once and reused at every iteration.
pub(crate) struct Workspace {
    pub(crate) residuals: Vec<f64>,
    pub(crate) jacobians: Vec<f64>,
    /// Per factor: `s = ‖r̃‖²` and `ρ(s)`; 0 for rejected factors.
    pub(crate) chi2: Vec<f64>,
    pub(crate) rho: Vec<f64>,
    pub(crate) valid: Vec<bool>,
    /// The gradient `g = J̃ᵀr̃`.
    pub(crate) gradient: Vec<f64>,
}

/// The totals of one evaluation of all factors.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Evaluation {
    /// `½Σρ(sₖ)`.
    pub(crate) cost: f64,
    /// `Σsₖ`, the unrobustified `χ²`.
    pub(crate) chi2: f64,
    /// Factors whose residual was undefined.
    pub(crate) invalid: usize,
}

/// A sparse non-linear least-squares problem `min ½ Σₖ ρₖ(rₖᵀ Λₖ rₖ)` over variables on
/// manifolds (thesis §2.2–2.3, §3.3).
pub struct Problem {
    pub(crate) values: Values,
    pub(crate) factors: Vec<FactorRecord>,
    pub(crate) whitening_pool: Vec<f64>,
    fixed: HashSet<VarKey>,
    eliminated_kinds: HashSet<u32>,
    pub(crate) structure: Option<Structure>,
    pub(crate) workspace: Option<Workspace>,
}

impl Default for Problem {
    fn default() -> Self {
        Self::new()
    }
}

impl Problem {
    /// An empty problem.
    pub fn new() -> Self {
        Problem {
            values: Values::new(),
            factors: Vec::new(),
            whitening_pool: Vec::new(),
            fixed: HashSet::new(),
            eliminated_kinds: HashSet::new(),
            structure: None,
            workspace: None,
        }
    }

    fn invalidate(&mut self) {
        self.structure = None;
        self.workspace = None;
    }

    /// Adds a variable with its initial value.
    pub fn add_variable<T: Manifold>(&mut self, value: T) -> Var<T> {
        self.invalidate();
        self.values.add(value)
    }

    /// The variables' current values.
    pub fn values(&self) -> &Values {
        &self.values
    }

    /// Mutable access to the values (to set them; add variables with
    /// [`add_variable`](Self::add_variable)).
    pub fn values_mut(&mut self) -> &mut Values {
        &mut self.values
    }

    /// The current value of a variable.
    pub fn value<T: Manifold>(&self, var: Var<T>) -> &T {
        self.values.get(var)
    }

    /// Holds a variable constant (or frees it again): the gauge can be fixed this way
    /// (thesis §3.3.2).
    pub fn set_fixed(&mut self, key: VarKey, fixed: bool) {
        let changed = if fixed {
            self.fixed.insert(key)
        } else {
            self.fixed.remove(&key)
        };
        if changed {
            self.invalidate();
        }
    }

    /// Whether a variable is held constant.
    pub fn is_fixed(&self, key: VarKey) -> bool {
        self.fixed.contains(&key)
    }

    /// Marks every variable of manifold type `T` for elimination by the Schur complement
    /// (thesis §3.3.5), e.g. the points of bundle adjustment. Their Hessian block must be
    /// block-diagonal: no factor may connect two of them.
    pub fn set_eliminated<T: Manifold>(&mut self, eliminated: bool) {
        let kind = match self.values.all::<T>().next() {
            Some((var, _)) => var.key().kind,
            None => return,
        };
        let changed = if eliminated {
            self.eliminated_kinds.insert(kind)
        } else {
            self.eliminated_kinds.remove(&kind)
        };
        if changed {
            self.invalidate();
        }
    }

    /// Whether any kind is marked for elimination.
    pub fn has_eliminated_variables(&self) -> bool {
        !self.eliminated_kinds.is_empty()
    }

    /// Adds a factor with its information matrix and an optional robust kernel.
    pub fn add_factor<F: Factor + 'static>(
        &mut self,
        factor: F,
        information: Information,
        kernel: Option<RobustKernel>,
    ) -> Result<FactorId, ProblemError> {
        let keys = factor.variables();
        if keys.is_empty() {
            return Err(ProblemError::NoVariables);
        }
        if keys.len() > MAX_ARITY {
            return Err(ProblemError::TooManyVariables(keys.len()));
        }
        let dim = factor.residual_dim();
        if dim == 0 {
            return Err(ProblemError::EmptyResidual);
        }
        let mut vars = [VarKey { kind: 0, index: 0 }; MAX_ARITY];
        for (k, key) in keys.iter().enumerate() {
            if !self.values.contains(*key) {
                return Err(ProblemError::UnknownVariable(*key));
            }
            if keys[..k].contains(key) {
                return Err(ProblemError::DuplicateVariable(*key));
            }
            vars[k] = *key;
        }
        if let Some(kernel) = kernel
            && !kernel.is_valid()
        {
            return Err(ProblemError::InvalidKernel(kernel));
        }
        let whitening = information.whitening(dim, &mut self.whitening_pool)?;
        self.invalidate();
        self.factors.push(FactorRecord {
            factor: Box::new(factor),
            vars,
            arity: keys.len(),
            dim,
            whitening,
            kernel,
        });
        Ok(FactorId(self.factors.len() - 1))
    }

    /// Number of factors.
    pub fn num_factors(&self) -> usize {
        self.factors.len()
    }

    /// Number of variables (free and fixed).
    pub fn num_variables(&self) -> usize {
        self.values.len()
    }

    /// The cost `½Σρ(rᵀΛr)` and `χ² = ΣrᵀΛr` at the current values, and the number of factors
    /// whose residual is undefined there.
    pub fn cost(&mut self) -> (f64, f64, usize) {
        self.ensure_structure().ok();
        let e = self.evaluate(false);
        (e.cost, e.chi2, e.invalid)
    }

    /// Builds the structure if the problem changed since it was last built.
    pub(crate) fn ensure_structure(&mut self) -> Result<(), ProblemError> {
        if self.structure.is_none() {
            let s = self.build_structure()?;
            let nf = self.factors.len();
            self.workspace = Some(Workspace {
                residuals: vec![0.0; s.residual_offsets[nf]],
                jacobians: vec![0.0; s.jacobian_offsets[nf]],
                chi2: vec![0.0; nf],
                rho: vec![0.0; nf],
                valid: vec![true; nf],
                gradient: vec![0.0; s.hessian.dim()],
            });
            self.structure = Some(s);
        }
        Ok(())
    }

    fn build_structure(&self) -> Result<Structure, ProblemError> {
        let values = &self.values;
        let num_kinds = values.num_kinds();
        // Which variables are used by some factor.
        let mut used: Vec<Vec<bool>> = (0..num_kinds as u32)
            .map(|k| vec![false; values.kind_len(k)])
            .collect();
        for rec in &self.factors {
            for key in &rec.vars[..rec.arity] {
                used[key.kind as usize][key.index as usize] = true;
            }
        }
        // Order: kept kinds first, eliminated kinds last; within, by (kind, index).
        let mut block_of: Vec<Vec<u32>> = (0..num_kinds as u32)
            .map(|k| vec![NONE; values.kind_len(k)])
            .collect();
        let mut block_keys = Vec::new();
        let mut dims = Vec::new();
        for pass_eliminated in [false, true] {
            for kind in 0..num_kinds as u32 {
                if self.eliminated_kinds.contains(&kind) != pass_eliminated {
                    continue;
                }
                for index in 0..values.kind_len(kind) as u32 {
                    let key = VarKey { kind, index };
                    if used[kind as usize][index as usize] && !self.fixed.contains(&key) {
                        block_of[kind as usize][index as usize] = block_keys.len() as u32;
                        block_keys.push(key);
                        dims.push(values.kind_dim(kind));
                    }
                }
            }
            if !pass_eliminated {
                // num_reduced is set below from this count.
            }
        }
        let num_reduced = block_keys
            .iter()
            .take_while(|k| !self.eliminated_kinds.contains(&k.kind))
            .count();
        let nb = block_keys.len();

        let nf = self.factors.len();
        let mut factor_blocks = Vec::with_capacity(nf);
        let mut jacobian_block_offsets = Vec::with_capacity(nf);
        let mut residual_offsets = Vec::with_capacity(nf + 1);
        let mut jacobian_offsets = Vec::with_capacity(nf + 1);
        residual_offsets.push(0);
        jacobian_offsets.push(0);
        let mut below: Vec<Vec<u32>> = vec![Vec::new(); nb];
        for (f, rec) in self.factors.iter().enumerate() {
            let mut blocks = [NONE; MAX_ARITY];
            let mut offs = [0u32; MAX_ARITY];
            let mut width = 0;
            for k in 0..rec.arity {
                let key = rec.vars[k];
                blocks[k] = block_of[key.kind as usize][key.index as usize];
                offs[k] = (rec.dim * width) as u32;
                width += values.dim(key);
            }
            let mut eliminated_seen = false;
            for a in 0..rec.arity {
                if blocks[a] == NONE {
                    continue;
                }
                if blocks[a] as usize >= num_reduced {
                    if eliminated_seen {
                        return Err(ProblemError::NotBlockDiagonal {
                            kind: values.kind_name(rec.vars[a]),
                            factor: f,
                        });
                    }
                    eliminated_seen = true;
                }
                for b in 0..rec.arity {
                    if blocks[b] != NONE && blocks[b] > blocks[a] {
                        below[blocks[a] as usize].push(blocks[b]);
                    }
                }
            }
            factor_blocks.push(blocks);
            jacobian_block_offsets.push(offs);
            residual_offsets.push(residual_offsets[f] + rec.dim);
            jacobian_offsets.push(jacobian_offsets[f] + rec.dim * width);
        }
        let hessian = BlockSymmetric::from_pattern(dims, below);

        // Contribution lists, grouped by stored block (counting sort).
        let mut h_count = vec![0usize; hessian.num_stored_blocks() + 1];
        let mut g_count = vec![0usize; nb + 1];
        let mut h_entries: Vec<(usize, Contribution)> = Vec::new();
        for (f, blocks) in factor_blocks.iter().enumerate() {
            let arity = self.factors[f].arity;
            for a in 0..arity {
                if blocks[a] == NONE {
                    continue;
                }
                g_count[blocks[a] as usize + 1] += 1;
                for b in 0..arity {
                    if blocks[b] == NONE || blocks[b] < blocks[a] {
                        continue;
                    }
                    // Block (row = blocks[b], col = blocks[a]) of the lower triangle.
                    let s = hessian
                        .find(blocks[b] as usize, blocks[a] as usize)
                        .expect("pattern holds every factor pair");
                    h_count[s + 1] += 1;
                    // Row block blocks[b], column block blocks[a]: H_ij += J_bᵀ·J_a.
                    h_entries.push((
                        s,
                        Contribution {
                            ja: jacobian_offsets[f] + jacobian_block_offsets[f][b] as usize,
                            jb: jacobian_offsets[f] + jacobian_block_offsets[f][a] as usize,
                            rows: self.factors[f].dim as u32,
                        },
                    ));
                }
            }
        }
        for i in 0..hessian.num_stored_blocks() {
            h_count[i + 1] += h_count[i];
        }
        let h_contrib_ptr = h_count.clone();
        let mut fill = h_count;
        let mut h_contrib = vec![
            Contribution {
                ja: 0,
                jb: 0,
                rows: 0
            };
            h_entries.len()
        ];
        for (s, c) in h_entries {
            h_contrib[fill[s]] = c;
            fill[s] += 1;
        }
        for i in 0..nb {
            g_count[i + 1] += g_count[i];
        }
        let g_contrib_ptr = g_count.clone();
        let mut gfill = g_count;
        let mut g_contrib = vec![
            GradientContribution {
                j: 0,
                r: 0,
                rows: 0
            };
            *g_contrib_ptr.last().unwrap_or(&0)
        ];
        for (f, blocks) in factor_blocks.iter().enumerate() {
            for a in 0..self.factors[f].arity {
                if blocks[a] != NONE {
                    let i = blocks[a] as usize;
                    g_contrib[gfill[i]] = GradientContribution {
                        j: jacobian_offsets[f] + jacobian_block_offsets[f][a] as usize,
                        r: residual_offsets[f],
                        rows: self.factors[f].dim as u32,
                    };
                    gfill[i] += 1;
                }
            }
        }
        Ok(Structure {
            block_of,
            block_keys,
            num_reduced,
            factor_blocks,
            jacobian_block_offsets,
            residual_offsets,
            jacobian_offsets,
            hessian,
            h_contrib_ptr,
            h_contrib,
            g_contrib_ptr,
            g_contrib,
        })
    }

    /// Evaluates every factor at the current values, whitened and robustified; with
    /// `jacobians` also their Jacobians. Parallel over factors.
    pub(crate) fn evaluate(&mut self, jacobians: bool) -> Evaluation {
        let s = self.structure.as_ref().expect("structure built");
        let ws = self.workspace.as_mut().expect("workspace built");
        let values = &self.values;
        let pool = &self.whitening_pool;
        let res_ptr = DisjointMut::new(&mut ws.residuals);
        let jac_ptr = DisjointMut::new(&mut ws.jacobians);
        let factors = &self.factors;
        ws.chi2
            .par_iter_mut()
            .zip(ws.rho.par_iter_mut())
            .zip(ws.valid.par_iter_mut())
            .enumerate()
            .with_min_len(64)
            .for_each(|(f, ((chi2, rho), valid))| {
                let rec = &factors[f];
                let r0 = s.residual_offsets[f];
                let (j0, j1) = (s.jacobian_offsets[f], s.jacobian_offsets[f + 1]);
                // SAFETY: factor f owns residuals[r0..r0+dim] and jacobians[j0..j1]; these
                // ranges are disjoint for distinct factors by construction of the prefix sums.
                let r = unsafe { res_ptr.slice(r0, rec.dim) };
                let jac = unsafe { jac_ptr.slice(j0, j1 - j0) };
                let blocks = &s.factor_blocks[f];
                let mut dims = [0usize; MAX_ARITY];
                let mut wanted = [false; MAX_ARITY];
                for k in 0..rec.arity {
                    dims[k] = values.dim(rec.vars[k]);
                    wanted[k] = blocks[k] != NONE;
                }
                let ok = if jacobians {
                    let mut j = Jacobians::new(jac, rec.dim, &dims[..rec.arity], wanted);
                    rec.factor.evaluate(values, r, Some(&mut j))
                } else {
                    rec.factor.evaluate(values, r, None)
                };
                let finite = r.iter().all(|x| x.is_finite())
                    && (!jacobians || jac.iter().all(|x| x.is_finite()));
                if !ok || !finite {
                    r.iter_mut().for_each(|x| *x = 0.0);
                    jac.iter_mut().for_each(|x| *x = 0.0);
                    *chi2 = 0.0;
                    *rho = 0.0;
                    *valid = false;
                    return;
                }
                *valid = true;
                rec.whitening.apply(pool, rec.dim, r);
                let sq: f64 = r.iter().map(|x| x * x).sum();
                let (rho_s, weight) = match &rec.kernel {
                    Some(k) => k.evaluate(sq),
                    None => (sq, 1.0),
                };
                *chi2 = sq;
                *rho = rho_s;
                let scale = weight.sqrt();
                if scale != 1.0 {
                    r.iter_mut().for_each(|x| *x *= scale);
                }
                if jacobians {
                    for k in 0..rec.arity {
                        if !wanted[k] {
                            continue;
                        }
                        let o = s.jacobian_block_offsets[f][k] as usize;
                        for c in 0..dims[k] {
                            let col = &mut jac[o + c * rec.dim..o + (c + 1) * rec.dim];
                            rec.whitening.apply(pool, rec.dim, col);
                            if scale != 1.0 {
                                col.iter_mut().for_each(|x| *x *= scale);
                            }
                        }
                    }
                }
            });
        // Sequential sums: the same bits whatever the thread count, and no allocation.
        let deterministic_sum = |v: &[f64]| -> f64 { v.iter().sum() };
        let cost = 0.5 * deterministic_sum(&ws.rho);
        let chi2 = deterministic_sum(&ws.chi2);
        let invalid = ws.valid.iter().filter(|v| !**v).count();
        Evaluation {
            cost,
            chi2,
            invalid,
        }
    }

    /// Assembles `H = J̃ᵀJ̃` and `g = J̃ᵀr̃` from the last linearisation, parallel over block
    /// columns (each writes only its own blocks: deterministic and free of conflicts).
    pub(crate) fn assemble(&mut self) {
        let s = self.structure.as_mut().expect("structure built");
        let ws = self.workspace.as_mut().expect("workspace built");
        let h = &mut s.hessian;
        let jac = &ws.jacobians;
        let res = &ws.residuals;
        let (h_ptr, h_contrib) = (&s.h_contrib_ptr, &s.h_contrib);
        let val_ptr = DisjointMut::new(&mut h.values);
        let h: &BlockSymmetric = h;
        let (col_ptr, rows, value_offsets, dims) = (&h.col_ptr, &h.rows, &h.value_offsets, &h.dims);
        let nb = dims.len();
        (0..nb).into_par_iter().with_min_len(16).for_each(|j| {
            let dj = dims[j];
            let range = h.column_values(j);
            let start = range.start;
            // SAFETY: block column j owns the contiguous value range of its blocks.
            let col_vals = unsafe { val_ptr.slice(start, range.len()) };
            for s_idx in col_ptr[j]..col_ptr[j + 1] {
                let di = dims[rows[s_idx] as usize];
                let o = value_offsets[s_idx] - start;
                let block = &mut col_vals[o..o + di * dj];
                block.iter_mut().for_each(|x| *x = 0.0);
                for c in &h_contrib[h_ptr[s_idx]..h_ptr[s_idx + 1]] {
                    let r = c.rows as usize;
                    kernels::add_at_b(
                        block,
                        &jac[c.ja..c.ja + r * di],
                        &jac[c.jb..c.jb + r * dj],
                        r,
                        di,
                        dj,
                        1.0,
                    );
                }
            }
        });
        let offsets = &h.offsets;
        let g_ptr = DisjointMut::new(&mut ws.gradient);
        let (gp, gc) = (&s.g_contrib_ptr, &s.g_contrib);
        (0..nb).into_par_iter().with_min_len(64).for_each(|i| {
            let di = dims[i];
            // SAFETY: block i owns gradient[offsets[i]..offsets[i]+di].
            let g = unsafe { g_ptr.slice(offsets[i], di) };
            g.iter_mut().for_each(|x| *x = 0.0);
            for c in &gc[gp[i]..gp[i + 1]] {
                let r = c.rows as usize;
                kernels::add_at_x(g, &jac[c.j..c.j + r * di], &res[c.r..c.r + r], r, di, 1.0);
            }
        });
    }

    /// Clears the elimination marks (returning them), e.g. to take covariances on the full
    /// system.
    pub(crate) fn take_eliminated(&mut self) -> HashSet<u32> {
        let e = std::mem::take(&mut self.eliminated_kinds);
        if !e.is_empty() {
            self.invalidate();
        }
        e
    }

    /// Restores elimination marks taken by [`take_eliminated`](Self::take_eliminated).
    pub(crate) fn restore_eliminated(&mut self, e: HashSet<u32>) {
        if !e.is_empty() {
            self.eliminated_kinds = e;
            self.invalidate();
        }
    }

    /// Applies the update `δ` (over the free variables, in block order) to the values.
    pub(crate) fn apply_step(&mut self, delta: &[f64]) {
        let s = self.structure.as_ref().expect("structure built");
        for (b, key) in s.block_keys.iter().enumerate() {
            let o = s.hessian.offsets[b];
            let d = s.hessian.dims[b];
            self.values.retract(*key, &delta[o..o + d]);
        }
    }
}
