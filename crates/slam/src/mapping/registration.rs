//! Local registration of a new keyframe (thesis §6.2.6).

use crate::map::{GraphError, KeyframeId, SlamGraph};
use lie::LieGroup;
use std::collections::BTreeMap;

/// Local registration of a new keyframe (thesis §6.2.6): an edge to every keyframe sharing at
/// least `theta` points with it, marginalised with the current relative pose (it is
/// un-marginalised when both ends enter the inner window), and always an edge to `fallback`
/// (the previous reference) so that the graph stays connected. Returns the new neighbours.
pub fn register_locally<const N: usize>(
    graph: &mut SlamGraph<N>,
    keyframe: KeyframeId,
    theta: usize,
    fallback: Option<KeyframeId>,
) -> Result<Vec<KeyframeId>, GraphError> {
    let mut shared: BTreeMap<KeyframeId, usize> = BTreeMap::new();
    let kf = graph
        .keyframe(keyframe)
        .ok_or(GraphError::UnknownKeyframe(keyframe))?;
    for &p in kf.observations().keys() {
        for &o in graph
            .point(p)
            .ok_or(GraphError::UnknownPoint(p))?
            .observers()
        {
            if o != keyframe {
                *shared.entry(o).or_default() += 1;
            }
        }
    }
    let mut neighbours: Vec<KeyframeId> = shared
        .iter()
        .filter(|&(_, &n)| n >= theta)
        .map(|(&k, _)| k)
        .collect();
    if let Some(f) = fallback
        && f != keyframe
        && !neighbours.contains(&f)
        && graph.keyframe(f).is_some()
    {
        neighbours.push(f);
    }
    let t_new = graph.pose(keyframe)?;
    for &j in &neighbours {
        let t_new_j = t_new.compose(&graph.pose(j)?.inverse());
        graph.add_edge(j, keyframe, Some(t_new_j))?;
    }
    Ok(neighbours)
}
