//! Insertion of an appearance-based (large) loop closure into the SLAM graph (thesis §6.4.2).

use crate::map::{GraphError, KeyframeId, PointId, SlamGraph};
use lie::Sim3;
use nalgebra::SVector;

/// Inserts an appearance-based loop closure (thesis §6.4.2) between the reference `query` and
/// an old keyframe `matched`: `matches` are points of the old map found in `query`, which
/// become its observations, and the edge `E_matched,query` is added, marginalised with the
/// measured `T_query,matched` (a similarity for monocular SLAM, whose scale then propagates
/// through the re-initialisation of eq. 6.3, thesis §6.2.7).
pub fn close_appearance_loop<const N: usize>(
    graph: &mut SlamGraph<N>,
    query: KeyframeId,
    matched: KeyframeId,
    query_from_matched: Sim3,
    matches: &[(PointId, SVector<f64, N>)],
) -> Result<(), GraphError> {
    for (p, z) in matches {
        graph.add_observation(query, *p, *z)?;
    }
    graph.add_edge(matched, query, Some(query_from_matched))?;
    Ok(())
}
