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

use crate::basis::{BasisKind, DomainError, DomainScratch, GimpDomain, eval_point_domain};
use crate::components::{DeformationGradient, PointId, Position, Support};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};
use crate::scene::{
    BasisRefinement, BasisWord, Choice, Kind, OptionSpec, Options, SceneApi, SceneSpec,
};

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

    fn scene_api(&self, api: &mut SceneApi) {
        let choice = |word, meaning| Choice {
            word,
            meaning: Some(meaning),
        };
        api.extend(
            "grid",
            OptionSpec::new(
                "gimp",
                Kind::Choice(vec![
                    choice("stretched", "domains follow the deformation, cpGIMP"),
                    choice("fixed", "domains keep their initial size, uGIMP"),
                ]),
                "GIMP only (default \"stretched\"): how the domains follow the deformation",
            ),
        )
        .extend(
            "grid",
            OptionSpec::new(
                "integration",
                Kind::Choice(vec![
                    choice("points", "the basis at the material points"),
                    choice("domain", "B-splines averaged over the points' domains"),
                ]),
                "B-splines only (default \"points\"): `\"domain\"` averages the basis over each point's box domain, stretched like cpGIMP's",
            ),
        )
        .word(BasisWord {
            word: "gimp",
            doc: "GIMP (Bardenhagen & Kober 2004): hat functions averaged over each point's box domain; `gimp: \"stretched\"` follows the diagonal of F (cpGIMP), `\"fixed\"` keeps the initial size (uGIMP). Domains are clipped to the grid. Use >= 2 points per cell",
            kind: |options| {
                let domain = match options.text("gimp") {
                    Some("fixed") => GimpDomain::Fixed,
                    _ => GimpDomain::Stretched,
                };
                Ok(BasisKind::Gimp { domain })
            },
            seeder: None,
        })
        .word(BasisWord {
            word: "cpdi",
            doc: "CPDI1 (Sadeghirad et al. 2011): hat functions averaged from the corners of each point's domain carried by F; a corner that a sheared domain tilts across a grid face (a symmetry plane, a fixed base) by up to a twentieth of a cell is projected onto it, as GIMP clips its domains; a domain leaving the grid otherwise is an error naming the point",
            kind: |_| Ok(BasisKind::Cpdi),
            seeder: None,
        })
        .word(domain_integration as BasisRefinement);
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
            if entity == Entity::PLACEHOLDER {
                continue; // another process's point (decomposed points)
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
        simulation.point_state(
            "point domains",
            |point, values| {
                if let Some(domain) = point.get::<ParticleDomain<D>>() {
                    values.extend(domain.initial_half_lengths.iter());
                }
            },
            |point, _, values| {
                if values.len() != D {
                    return Err(format!("{} half-lengths, not {D}", values.len()));
                }
                point.insert(ParticleDomain::<D> {
                    initial_half_lengths: SVector::from_column_slice(values),
                });
                Ok(())
            },
        );
        simulation.provide(Hook::Basis, self.name(), evaluate_domain_basis::<D>);
    }
}

/// `integration: "domain"`: B-splines averaged over the points' domains.
fn domain_integration(kind: BasisKind, options: &Options) -> Result<BasisKind, String> {
    if options.text("integration") != Some("domain") {
        return Ok(kind);
    }
    match kind {
        BasisKind::BSpline { order } => Ok(BasisKind::BSplineDomain { order }),
        _ => Err(format!(
            "grid(...): integration \"domain\" is an option of basis \"bspline\" (for the hat functions it is basis \"gimp\"), got basis {:?}",
            options.text("basis").unwrap_or_default()
        )),
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
