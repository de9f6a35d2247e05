//! The variable store: values of every kind (manifold type), addressed by typed handles.

use crate::manifold::Manifold;
use std::any::{Any, TypeId};
use std::collections::HashMap;
use std::marker::PhantomData;

/// An untyped handle of a variable: its kind (manifold type) and index within the kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VarKey {
    /// Which kind (manifold type) the variable belongs to.
    pub kind: u32,
    /// The index within its kind.
    pub index: u32,
}

/// A typed handle of a variable of manifold type `T`.
pub struct Var<T> {
    key: VarKey,
    _type: PhantomData<fn() -> T>,
}

impl<T> Var<T> {
    /// The untyped key.
    #[inline]
    pub fn key(&self) -> VarKey {
        self.key
    }
}

impl<T> Clone for Var<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Var<T> {}
impl<T> std::fmt::Debug for Var<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Var({}:{})", self.key.kind, self.key.index)
    }
}
impl<T> PartialEq for Var<T> {
    fn eq(&self, other: &Self) -> bool {
        self.key == other.key
    }
}
impl<T> Eq for Var<T> {}
impl<T> std::hash::Hash for Var<T> {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.key.hash(state)
    }
}

/// Type-erased operations on one kind's values.
pub(crate) trait AnyKind: Send + Sync {
    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
    fn dim(&self) -> usize;
    fn len(&self) -> usize;
    fn name(&self) -> &'static str;
    fn retract(&mut self, index: usize, delta: &[f64]);
    fn is_finite(&self, index: usize) -> bool;
    /// Copies the values into the backup (no allocation once the backup has grown).
    fn save(&mut self);
    /// Restores the values from the backup.
    fn restore(&mut self);
    fn clone_box(&self) -> Box<dyn AnyKind>;
}

#[derive(Clone)]
pub(crate) struct Kind<T: Manifold> {
    pub(crate) values: Vec<T>,
    backup: Vec<T>,
}

impl<T: Manifold> AnyKind for Kind<T> {
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
    fn dim(&self) -> usize {
        T::DIM
    }
    fn len(&self) -> usize {
        self.values.len()
    }
    fn name(&self) -> &'static str {
        T::NAME
    }
    #[inline]
    fn retract(&mut self, index: usize, delta: &[f64]) {
        self.values[index].retract(delta);
    }
    fn is_finite(&self, index: usize) -> bool {
        self.values[index].is_finite()
    }
    fn save(&mut self) {
        self.backup.clear();
        self.backup.extend_from_slice(&self.values);
    }
    fn restore(&mut self) {
        self.values.copy_from_slice(&self.backup);
    }
    fn clone_box(&self) -> Box<dyn AnyKind> {
        Box::new(self.clone())
    }
}

/// Values of all variables, grouped by kind (manifold type).
#[derive(Default)]
pub struct Values {
    kinds: Vec<Box<dyn AnyKind>>,
    kind_of_type: HashMap<TypeId, u32>,
}

impl Clone for Values {
    fn clone(&self) -> Self {
        Values {
            kinds: self.kinds.iter().map(|k| k.clone_box()).collect(),
            kind_of_type: self.kind_of_type.clone(),
        }
    }
}

impl std::fmt::Debug for Values {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_map();
        for k in &self.kinds {
            d.entry(&k.name(), &k.len());
        }
        d.finish()
    }
}

impl Values {
    /// An empty store.
    pub fn new() -> Self {
        Self::default()
    }

    fn kind_index<T: Manifold>(&mut self) -> u32 {
        if let Some(&k) = self.kind_of_type.get(&TypeId::of::<T>()) {
            return k;
        }
        let k = self.kinds.len() as u32;
        self.kinds.push(Box::new(Kind::<T> {
            values: Vec::new(),
            backup: Vec::new(),
        }));
        self.kind_of_type.insert(TypeId::of::<T>(), k);
        k
    }

    /// Adds a variable with initial value `value`.
    pub fn add<T: Manifold>(&mut self, value: T) -> Var<T> {
        let kind = self.kind_index::<T>();
        let store = self.kind_mut::<T>(kind);
        let index = store.values.len() as u32;
        store.values.push(value);
        Var {
            key: VarKey { kind, index },
            _type: PhantomData,
        }
    }

    #[inline]
    fn kind_ref<T: Manifold>(&self, kind: u32) -> &Kind<T> {
        self.kinds[kind as usize]
            .as_any()
            .downcast_ref::<Kind<T>>()
            .expect("variable handle used with a value store of another layout")
    }

    #[inline]
    fn kind_mut<T: Manifold>(&mut self, kind: u32) -> &mut Kind<T> {
        self.kinds[kind as usize]
            .as_any_mut()
            .downcast_mut::<Kind<T>>()
            .expect("variable handle used with a value store of another layout")
    }

    /// The value of a variable.
    #[inline]
    pub fn get<T: Manifold>(&self, var: Var<T>) -> &T {
        &self.kind_ref::<T>(var.key.kind).values[var.key.index as usize]
    }

    /// Mutable access to the value of a variable.
    #[inline]
    pub fn get_mut<T: Manifold>(&mut self, var: Var<T>) -> &mut T {
        &mut self.kind_mut::<T>(var.key.kind).values[var.key.index as usize]
    }

    /// Sets the value of a variable.
    pub fn set<T: Manifold>(&mut self, var: Var<T>, value: T) {
        *self.get_mut(var) = value;
    }

    /// All values of kind `T`, in the order they were added, with their handles.
    pub fn all<T: Manifold>(&self) -> impl Iterator<Item = (Var<T>, &T)> {
        let kind = self.kind_of_type.get(&TypeId::of::<T>()).copied();
        let slice: &[T] = match kind {
            Some(k) => &self.kind_ref::<T>(k).values,
            None => &[],
        };
        slice.iter().enumerate().map(move |(i, v)| {
            (
                Var {
                    key: VarKey {
                        kind: kind.unwrap_or(0),
                        index: i as u32,
                    },
                    _type: PhantomData,
                },
                v,
            )
        })
    }

    /// The tangent dimension of a variable.
    #[inline]
    pub fn dim(&self, key: VarKey) -> usize {
        self.kinds[key.kind as usize].dim()
    }

    /// The manifold name of a variable, e.g. `"SE(3)"`.
    pub fn kind_name(&self, key: VarKey) -> &'static str {
        self.kinds[key.kind as usize].name()
    }

    /// Whether `key` names a variable of this store.
    pub fn contains(&self, key: VarKey) -> bool {
        (key.kind as usize) < self.kinds.len()
            && (key.index as usize) < self.kinds[key.kind as usize].len()
    }

    /// Number of variables of all kinds.
    pub fn len(&self) -> usize {
        self.kinds.iter().map(|k| k.len()).sum()
    }

    /// `true` when the store holds no variable.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of kinds.
    pub(crate) fn num_kinds(&self) -> usize {
        self.kinds.len()
    }

    /// Number of variables of a kind.
    pub(crate) fn kind_len(&self, kind: u32) -> usize {
        self.kinds[kind as usize].len()
    }

    /// Dimension of a kind.
    pub(crate) fn kind_dim(&self, kind: u32) -> usize {
        self.kinds[kind as usize].dim()
    }

    /// Applies the update `δ` to a variable (see [`Manifold::retract`]).
    #[inline]
    pub fn retract(&mut self, key: VarKey, delta: &[f64]) {
        self.kinds[key.kind as usize].retract(key.index as usize, delta);
    }

    /// Whether a variable's value is finite.
    pub fn is_finite(&self, key: VarKey) -> bool {
        self.kinds[key.kind as usize].is_finite(key.index as usize)
    }

    pub(crate) fn save(&mut self) {
        for k in &mut self.kinds {
            k.save();
        }
    }

    pub(crate) fn restore(&mut self) {
        for k in &mut self.kinds {
            k.restore();
        }
    }
}
