//! Linear FEM (`basis: "fem"`) as a module: the body-fitted mesh replaces the background
//! grid's basis (see `crate::fem` for why the MPM stages then are exactly updated-Lagrangian
//! linear FEM).
//!
//! * Setup (`setup.rs`): every point is an integration point of its element ([`ElementPoint`]),
//!   the [`FemMesh`] resource holds the element topology and reference node positions.
//! * [`evaluate_element_basis`] provides `Hook::Basis`: at the start of a load step every
//!   integration point evaluates its element's shape functions at its fixed parent coordinates
//!   ξ_p, with spatial gradients from the CURRENT node positions (`GridNode::position`, which
//!   move with the body): `N_a(ξ_p)` and `∇_n N_a = J_n⁻ᵀ ∇_ξ N_a` (`fem::element_weights`).
//!   They are kept for the whole step in `Support`, exactly like the MPM basis, so every later
//!   stage is unchanged. The element's nodes become active.
//! * [`advance_mesh`] (`Hook::PointUpdate`): the mesh moves with the body, `x_i += Δu_i` for
//!   every active node, after the points were updated. This replaces the MPM grid reset of the
//!   node geometry (the grid fields are still cleared), so the next step's elements are the
//!   current configuration.
//! * [`write_mesh`] provides `Hook::GridOutput`: the deformed mesh as `grid_NNNN.vtu` (in place
//!   of the background grid), so the MPM ParaView workflow applies unchanged: the mesh nodes at
//!   their current positions and one `VTK_LINE`, `VTK_QUAD` or `VTK_HEXAHEDRON` per element,
//!   with point data `displacement` (x_i - X_i) and `displacement_increment` (the step's Δu_i)
//!   and cell data `integration_points` (points per element).
//!
//! Tractions and the ghost penalty act through the background grid and do not apply.

mod setup;

pub use setup::{attach_mesh, move_reference_nodes};

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::BasisKind;
use crate::checkpoint::{self, CheckpointPart};
use crate::components::{GridNode, PointId, Support};
use crate::fem::{Mesh, element_weights};
use crate::output::{Cells, Field, write_vtu};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock,
};
use crate::scene::{BasisWord, SceneApi, SceneSpec, seed_element_points};
use crate::stages::output::{OutputPlan, pad};

/// The body-fitted mesh (element topology, reference node positions). The current node
/// positions are the `GridNode` positions.
#[derive(Resource, Clone, Debug)]
pub struct FemMesh<const D: usize>(pub Mesh<D>);

/// The element an integration point belongs to and its parent coordinates ξ in `[-1, 1]^D`,
/// both fixed for the whole run.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ElementPoint<const D: usize> {
    pub element: usize,
    pub xi: SVector<f64, D>,
}

/// The module: used by `basis: "fem"`.
#[derive(Clone, Copy, Debug, Default)]
pub struct FemMeshModule;

impl Plugin for FemMeshModule {
    fn name(&self) -> &'static str {
        "finite-element mesh"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.word(BasisWord {
            word: "fem",
            doc: "updated-Lagrangian linear finite elements (bars, quads, hexahedra) on the body-fitted mesh of grid cells: a body must be made of whole cells, and its `ppc` is the number of Gauss points per direction (`order` is ignored)",
            kind: |_| Ok(BasisKind::Fem),
            seeder: Some(|grid, gauss_points, inside| {
                seed_element_points(grid, gauss_points, inside)
                    .map(|seeded| seeded.map_err(|partial| partial.message()))
            }),
        });
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis == BasisKind::Fem
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        self.used_by(spec)
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        if let Err(why) = attach_mesh::<D>(simulation.world()) {
            simulation.fail(why);
            return;
        }
        simulation
            .checkpoint(CheckpointPart {
                name: "mesh nodes",
                save: save_mesh_nodes::<D>,
                restore: restore_mesh_nodes::<D>,
            })
            .point_state(
                "element points",
                |point, values| {
                    if let Some(at) = point.get::<ElementPoint<D>>() {
                        values.push(at.element as f64);
                        values.extend(at.xi.iter());
                    }
                },
                |point, _, values| match values.split_first() {
                    Some((&element, xi)) if xi.len() == D => {
                        point.insert(ElementPoint::<D> {
                            element: element as usize,
                            xi: SVector::from_column_slice(xi),
                        });
                        Ok(())
                    }
                    _ => Err(format!(
                        "{} numbers, not an element and {D} coordinates",
                        values.len()
                    )),
                },
            )
            .provide(Hook::Basis, self.name(), evaluate_element_basis::<D>)
            .add_systems(Hook::PointUpdate, advance_mesh::<D>)
            .provide(Hook::GridOutput, self.name(), write_mesh::<D>);
    }
}

/// The current node positions, in node order.
fn save_mesh_nodes<const D: usize>(world: &mut World) -> Vec<f64> {
    let mut nodes: Vec<_> = world
        .query::<&GridNode<D>>()
        .iter(world)
        .map(|n| (n.index, n.position))
        .collect();
    nodes.sort_by_key(|(index, _)| *index);
    nodes.iter().flat_map(|(_, x)| x.iter().copied()).collect()
}

fn restore_mesh_nodes<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut query = world.query::<&mut GridNode<D>>();
    let count = query.iter(world).len();
    let records: Vec<&[f64]> = checkpoint::records(values, D, count)?.collect();
    for mut node in query.iter_mut(world) {
        node.position = SVector::from_column_slice(records[node.index]);
    }
    Ok(())
}

/// Scratch memory: the current node positions by node index, and one element's corners.
#[derive(Default)]
pub struct ElementScratch<const D: usize> {
    positions: Vec<SVector<f64, D>>,
    corners: Vec<SVector<f64, D>>,
}

#[allow(clippy::too_many_arguments)]
pub fn evaluate_element_basis<const D: usize>(
    mesh: Res<FemMesh<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<ElementScratch<D>>,
    nodes: Query<&GridNode<D>>,
    mut points: Query<(&PointId, &ElementPoint<D>, &mut Support<D>)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let ElementScratch { positions, corners } = &mut *scratch;
    positions.resize(fields.active.len(), SVector::zeros());
    for node in nodes.iter() {
        positions[node.index] = node.position;
    }
    for (id, point, mut support) in points.iter_mut() {
        let element_nodes = mesh.0.element_nodes(point.element);
        corners.clear();
        corners.extend(element_nodes.iter().map(|&n| positions[n]));
        if let Err(degenerate) = element_weights(element_nodes, corners, &point.xi, &mut support.0)
        {
            status.fail(SolverError::BadPointState {
                point: id.0,
                step: step.number,
                iteration: 0,
                why: format!("element {}: {degenerate}", point.element),
            });
            return;
        }
        for &node in element_nodes {
            fields.active[node] = true;
        }
    }
}

pub fn advance_mesh<const D: usize>(
    fields: Res<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    mut nodes: Query<&mut GridNode<D>>,
) {
    let _timer = clock.time(Stage::UpdatePoints);
    for mut node in nodes.iter_mut() {
        let i = node.index;
        if fields.active[i] {
            node.position += fields.increment[i];
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub fn write_mesh<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mesh: Res<FemMesh<D>>,
    fields: Res<GridFields<D>>,
    mut plan: ResMut<OutputPlan>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    nodes: Query<&GridNode<D>>,
    points: Query<&ElementPoint<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let mesh = &mesh.0;
    let mut current = mesh.reference_positions.clone();
    for node in nodes.iter() {
        current[node.index] = node.position;
    }
    let used = mesh.mesh_nodes();
    let positions: Vec<[f64; 3]> = used.iter().map(|&n| pad(&current[n])).collect();
    let displacement: Vec<f64> = used
        .iter()
        .flat_map(|&n| pad(&(current[n] - mesh.reference_positions[n])))
        .collect();
    let increment: Vec<f64> = used
        .iter()
        .flat_map(|&n| pad(&fields.increment[n]))
        .collect();
    let mut per_element = vec![0.0; mesh.element_count()];
    for point in points.iter() {
        per_element[point.element] += 1.0;
    }
    let name = format!("grid_{:04}.vtu", step.number);
    let cells = Cells {
        kind: Mesh::<D>::vtk_kind(),
        connectivity: mesh.vtk_connectivity(),
    };
    let result = write_vtu(
        &plan.dir.join(&name),
        &positions,
        &cells,
        &[
            Field::new("displacement", 3, &displacement),
            Field::new("displacement_increment", 3, &increment),
        ],
        &[Field::scalar("integration_points", &per_element)],
    )
    .and_then(|()| plan.grid.push(step.series_time(stage.as_deref()), &name));
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!("{name}: {e}"),
        });
    }
}
