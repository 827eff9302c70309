//! Building the FEM part of a world: the mesh resource from the integration points the scene
//! seeded, and an optional distortion of the reference mesh before the run.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use super::{ElementPoint, FemMesh};
use crate::components::{
    GridNode, Mass, PointId, Position, ReferencePosition, ReferenceVolume, Volume,
};
use crate::fem::{Mesh, jacobian_determinant, map_to_element};
use crate::resources::{Grid, LoadStep};

/// Makes the world a linear-FEM world: every point is an integration point of the grid cell
/// that contains it (its element gets parent coordinates ξ from its position, see
/// [`Mesh::locate`]), the cells holding points become the elements, and the [`FemMesh`]
/// resource is inserted. Needs the [`Grid`] resource (order 1) and the points' [`Position`]s,
/// still in the reference configuration.
pub fn attach_mesh<const D: usize>(world: &mut World) -> Result<(), String> {
    let grid = world
        .get_resource::<Grid<D>>()
        .ok_or("the grid must exist before the mesh")?
        .0
        .clone();
    let mut query = world.query::<(Entity, &PointId, &Position<D>)>();
    let mut located = Vec::new();
    for (entity, id, position) in query.iter(world) {
        let cell = grid.cell_of(&position.0).map_err(|outside| {
            format!("integration point {} is outside the grid: {outside}", id.0)
        })?;
        located.push((entity, grid.cell_index(cell), position.0));
    }
    let mesh = Mesh::from_cells(&grid, located.iter().map(|&(_, cell, _)| cell))?;
    for (entity, _, x) in located {
        let (element, xi) = mesh
            .locate(&grid, &x)
            .ok_or_else(|| format!("no element at {x:?}"))?;
        world
            .entity_mut(entity)
            .insert(ElementPoint { element, xi });
    }
    world.insert_resource(FemMesh(mesh));
    Ok(())
}

/// Moves the reference mesh nodes before the first load step: node `i` at `X_i` goes to
/// `X_i + offset(i, X_i)` (only mesh nodes move), and every integration point keeps its element
/// and ξ while its reference position, volume and mass follow the new element geometry:
/// `X_p = Σ N_a(ξ_p) X_a`, `V0_p = w_p det J_0(ξ_p)` (the weight `w_p` recovered from the old
/// volume and Jacobian), mass at unchanged density. For distorted-mesh studies and patch tests;
/// call it before writing the initial state. Fails, changing nothing, if a step was already
/// solved or an element would be inverted at one of its points.
pub fn move_reference_nodes<const D: usize>(
    world: &mut World,
    offset: impl Fn(usize, &SVector<f64, D>) -> SVector<f64, D>,
) -> Result<(), String> {
    if world.resource::<LoadStep>().number != 0 {
        return Err("the reference mesh can only move before the first load step".into());
    }
    let mesh = world
        .get_resource::<FemMesh<D>>()
        .ok_or("the world has no finite-element mesh")?
        .0
        .clone();
    let old = mesh.reference_positions.clone();
    let mut new = old.clone();
    for &node in mesh.mesh_nodes() {
        new[node] += offset(node, &old[node]);
    }
    let corners = |positions: &[SVector<f64, D>], element: usize| -> Vec<SVector<f64, D>> {
        mesh.element_nodes(element)
            .iter()
            .map(|&n| positions[n])
            .collect()
    };
    // (entity, X, V0, m) for every point, all checked before anything changes
    let mut query = world.query::<(Entity, &PointId, &ElementPoint<D>, &ReferenceVolume, &Mass)>();
    let mut updates = Vec::new();
    for (entity, id, point, volume, mass) in query.iter(world) {
        let before = jacobian_determinant(&corners(&old, point.element), &point.xi)
            .map_err(|e| format!("integration point {}: {e}", id.0))?;
        let after_corners = corners(&new, point.element);
        let after = jacobian_determinant(&after_corners, &point.xi).map_err(|e| {
            format!(
                "moving the nodes would invert element {} at integration point {}: {e}",
                point.element, id.0
            )
        })?;
        let v0 = volume.0 / before * after;
        updates.push((
            entity,
            map_to_element(&after_corners, &point.xi),
            v0,
            mass.0 / volume.0 * v0,
        ));
    }
    for (entity, x, v0, m) in updates {
        let mut entity = world.entity_mut(entity);
        entity.insert((
            Position(x),
            ReferencePosition(x),
            ReferenceVolume(v0),
            Volume(v0),
            Mass(m),
        ));
    }
    let mut nodes = world.query::<&mut GridNode<D>>();
    for mut node in nodes.iter_mut(world) {
        node.position = new[node.index];
    }
    world.resource_mut::<FemMesh<D>>().0.reference_positions = new;
    Ok(())
}
