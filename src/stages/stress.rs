//! Newton stage 1: the trial state of every point for the current displacement increment:
//! Δf = I + Σ Δu_i ⊗ ∇_n N_i, F = Δf F^n, and the material's stress and tangent (`mechanics`).
//!
//! A point with a [`ModifiedIncrement`] (set at `Hook::Kinematics`, e.g. by F-bar) is evaluated
//! at that increment instead of its own, its spatial gradients still from its own `Δf`.
//!
//! One system per material kind ([`update_stress`] monomorphised for `M`), each over the points
//! of that kind only: the hot loop knows its model at compile time, and a scene that mixes kinds
//! runs one system per kind. The systems are added by the kinds' modules
//! (`effects::materials::MaterialModule`), never by the core.
//!
//! The points are split across threads (`parallel`): each point's update is independent, so the
//! result is the same for any thread count.
//!
//! History: the trial history of an iterate is computed from the committed one and kept beside
//! it ([`PointHistory::trial`]); [`commit_history`] makes it the committed one after a converged
//! load step. A failed attempt leaves the committed history untouched, so a cut step restarts
//! from it.

use bevy_ecs::prelude::*;

use crate::components::{DeformationGradient, ModifiedIncrement, PointId, Support, Trial};
use crate::material::Material;
use crate::mechanics::{
    increment_gradient, trial_state_with_history, trial_state_with_modified_increment,
};
use crate::parallel;
use crate::resources::{GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock};

/// The point's constitutive model.
///
/// Stored in a sparse set, not in the points' table: the material module inserts it after the
/// points are spawned, and a table component would move every point into a new table grown by
/// doubling, leaving the spawn table allocated and empty (about 0.55 kB per 2D point; see
/// docs/performance.md). A sparse-set component leaves the points where they are.
#[derive(Component, Clone, Debug, PartialEq)]
#[component(storage = "SparseSet")]
pub struct PointMaterial<M: Material>(pub M);

/// The history of a point whose model has one: committed at the end of the last converged
/// load step, and that of the current Newton iterate. In a sparse set, as [`PointMaterial`].
#[derive(Component, Clone, Debug, PartialEq)]
#[component(storage = "SparseSet")]
pub struct PointHistory<M: Material> {
    pub committed: M::History,
    pub trial: M::History,
}

impl<M: Material> Default for PointHistory<M> {
    fn default() -> Self {
        Self {
            committed: M::History::default(),
            trial: M::History::default(),
        }
    }
}

/// Points per batch of the stress update.
const STRESS_BATCH: usize = 1 << 16;

#[allow(clippy::type_complexity)]
pub fn update_stress<const D: usize, M: Material>(
    fields: Res<GridFields<D>>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(
        &PointId,
        &Support<D>,
        &DeformationGradient<D>,
        &PointMaterial<M>,
        &mut Trial<D>,
        Option<&mut PointHistory<M>>,
        Option<&ModifiedIncrement<D>>,
    )>,
) {
    let _timer = clock.time(Stage::StressUpdate);
    let none = M::History::default();
    // The points a batch at a time (their rows of references take ~120 B a point: collected
    // all at once they were the stress update's peak of memory); each batch in one part per
    // thread (`parallel`), each part keeping the first point it could not update.
    let mut rows = points.iter_mut();
    let mut batch = Vec::with_capacity(STRESS_BATCH.min(rows.len()));
    let mut first_failure = None;
    while first_failure.is_none() {
        batch.clear();
        batch.extend(rows.by_ref().take(STRESS_BATCH));
        if batch.is_empty() {
            break;
        }
        let mut failures = vec![None; parallel::part_count(batch.len())];
        parallel::for_each_part(&mut batch, &mut failures, |_, part, failure| {
            for (id, support, f, material, trial, history, modified) in part.iter_mut() {
                let df = increment_gradient(&support.0, |node| fields.increment[node]);
                let committed = history.as_ref().map_or(&none, |h| &h.committed);
                let evaluated = match modified {
                    None => trial_state_with_history(&material.0, committed, &f.0, &df),
                    Some(seen) => trial_state_with_modified_increment(
                        &material.0,
                        committed,
                        &f.0,
                        &df,
                        &seen.0,
                    ),
                };
                match evaluated {
                    Ok((state, trial_history)) => {
                        trial.0 = state;
                        if let Some(history) = history {
                            history.trial = trial_history;
                        }
                    }
                    Err(why) => {
                        *failure = Some((id.0, why.to_string()));
                        return;
                    }
                }
            }
        });
        first_failure = failures.into_iter().flatten().next();
    }
    // The first failing point in the points' order, whatever the thread count.
    if let Some((point, why)) = first_failure {
        status.fail(SolverError::BadPointState {
            point,
            step: step.number,
            iteration: newton.iterations,
            why,
        });
    }
}

/// After a converged load step: the trial history becomes the committed one.
pub fn commit_history<M: Material>(mut points: Query<&mut PointHistory<M>>) {
    for mut history in points.iter_mut() {
        let history = &mut *history;
        history.committed.clone_from(&history.trial);
    }
}
