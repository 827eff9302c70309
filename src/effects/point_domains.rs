//! Point domains: the methods whose weights average the grid functions over each point's
//! domain instead of evaluating them at its centre — GIMP (`basis: "gimp"`), CPDI
//! (`basis: "cpdi"`) and B-splines with `integration: "domain"` (kernels: `basis::domain`).
//!
//! Every point gets its initial domain ([`ParticleDomain`]: the half-lengths of the box it owns
//! at seeding), and [`evaluate_domain_basis`] replaces the point basis at `Hook::Basis`: at the
//! start of each step it builds the point's domain from its converged deformation gradient and
//! averages the grid functions over it. The weights are then frozen for the step like any
//! basis, so every later stage is unchanged.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::{DomainError, DomainScratch, eval_point_domain};
use crate::components::{DeformationGradient, PointId, Position, Support};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};
use crate::scene::SceneSpec;

/// The initial domain of a material point: the half-lengths `lp0_k` of the box the point owns
/// at seeding (`h_k / (2 ppc_k)` on the lattice; its share of the overlap where a box region
/// cuts a cell).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ParticleDomain<const D: usize> {
    pub initial_half_lengths: SVector<f64, D>,
}

/// The module: used by the bases that average over point domains.
#[derive(Clone, Copy, Debug, Default)]
pub struct PointDomainsModule;

impl Plugin for PointDomainsModule {
    fn name(&self) -> &'static str {
        "basis averaged over domains"
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis.uses_point_domain()
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        self.used_by(spec)
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let entities = simulation.point_entities();
        let mut batch = Vec::with_capacity(entities.len());
        let seeds = spec.bodies.iter().flat_map(|body| {
            body.points
                .iter()
                .map(move |seed| (body.name.as_str(), seed))
        });
        for (&entity, (body, seed)) in entities.iter().zip(seeds) {
            let lengths = &seed.half_lengths;
            if lengths.len() != D || lengths.iter().any(|&l| !(l > 0.0 && l.is_finite())) {
                simulation.fail(format!(
                    "body '{body}': the point at {:?} has domain half-lengths {lengths:?}, not {D} positive lengths",
                    seed.position
                ));
                return;
            }
            let initial_half_lengths = SVector::<f64, D>::from_fn(|k, _| lengths[k]);
            batch.push((
                entity,
                ParticleDomain::<D> {
                    initial_half_lengths,
                },
            ));
        }
        simulation.world().insert_batch(batch);
        simulation.provide(Hook::Basis, self.name(), evaluate_domain_basis::<D>);
    }
}

/// The weights of every point averaged over its domain at the start of the step.
pub fn evaluate_domain_basis<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<DomainScratch<D>>,
    mut points: Query<(
        &PointId,
        &Position<D>,
        &DeformationGradient<D>,
        &ParticleDomain<D>,
        &mut Support<D>,
    )>,
) {
    let _timer = clock.time(Stage::Connectivity);
    for (id, position, f, domain, mut support) in points.iter_mut() {
        let evaluated = eval_point_domain(
            &grid.0,
            &position.0,
            &f.0,
            &domain.initial_half_lengths,
            &mut scratch,
            &mut support.0,
        );
        if let Err(error) = evaluated {
            status.fail(match error {
                DomainError::Outside(_) => SolverError::PointOutsideGrid {
                    point: id.0,
                    position: position.0.iter().copied().collect(),
                    step: step.number,
                },
                other => SolverError::Module {
                    step: step.number,
                    what: format!(
                        "the domain of material point {} cannot be used: {other}",
                        id.0
                    ),
                    recoverable: false,
                },
            });
            return;
        }
        for w in &support.0 {
            fields.active[w.node] = true;
        }
    }
}
