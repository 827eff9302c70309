//! The body-fitted mesh: elements are grid cells, nodes are grid vertices.
//!
//! A [`Mesh`] holds the topology (the `2^D` nodes of every element, in the corner order of
//! [`super::element`]), the grid cell each element came from, and the reference node positions.
//! Node numbers are the grid's node numbers, which on an order-1 grid are its vertex numbers
//! (axis 0 fastest), so the mesh shares `GridFields`, DOF numbering and constraints with MPM.
//! The current node positions are not stored here: they live on the node entities, which move
//! with the body.

use nalgebra::SVector;

use super::element::corner_count;
use crate::basis::GridBasis;
use crate::output::CellKind;

/// No element in this grid cell.
const NO_ELEMENT: u32 = u32::MAX;

/// Element topology of a body-fitted mesh on a background grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh<const D: usize> {
    /// `2^D` node numbers per element, corner order (axis 0 fastest).
    element_nodes: Vec<usize>,
    /// The grid cell of each element.
    element_cells: Vec<usize>,
    /// Element number of each grid cell (`NO_ELEMENT` where the body is not).
    cell_elements: Vec<u32>,
    /// Nodes used by at least one element, increasing.
    mesh_nodes: Vec<usize>,
    /// Reference position of every grid node (also those outside the mesh).
    pub reference_positions: Vec<SVector<f64, D>>,
}

impl<const D: usize> Mesh<D> {
    /// The mesh of the given grid cells (flat cell indices, any order, repeats ignored).
    /// Elements are numbered in increasing cell order. The grid must have order 1 (its nodes
    /// are its vertices) and every cell must exist.
    pub fn from_cells(
        grid: &GridBasis<D>,
        cells: impl IntoIterator<Item = usize>,
    ) -> Result<Self, String> {
        if grid.nodes_per_axis() != grid.vertices_per_axis() {
            return Err(format!(
                "a finite-element mesh needs a grid whose nodes are its vertices (order 1), got order {}",
                grid.axes[0].order()
            ));
        }
        let cell_count = grid.num_cells();
        let mut cell_elements = vec![NO_ELEMENT; cell_count];
        for cell in cells {
            let slot = cell_elements.get_mut(cell).ok_or_else(|| {
                format!("cell {cell} is not a cell of the grid ({cell_count} cells)")
            })?;
            *slot = 0;
        }
        let mut element_cells = Vec::new();
        let mut element_nodes = Vec::new();
        let mut corners = Vec::with_capacity(corner_count(D));
        for (cell, slot) in cell_elements.iter_mut().enumerate() {
            if *slot == NO_ELEMENT {
                continue;
            }
            *slot = u32::try_from(element_cells.len())
                .ok()
                .filter(|&e| e != NO_ELEMENT)
                .ok_or_else(|| "too many elements".to_string())?;
            element_cells.push(cell);
            grid.cell_vertices(cell, &mut corners);
            element_nodes.extend_from_slice(&corners);
        }
        let mut mesh_nodes = element_nodes.clone();
        mesh_nodes.sort_unstable();
        mesh_nodes.dedup();
        Ok(Self {
            element_nodes,
            element_cells,
            cell_elements,
            mesh_nodes,
            reference_positions: (0..grid.num_nodes())
                .map(|node| grid.node_position(node))
                .collect(),
        })
    }

    /// Number of elements.
    pub fn element_count(&self) -> usize {
        self.element_cells.len()
    }

    /// The `2^D` nodes of element `element`, corner order.
    #[inline]
    pub fn element_nodes(&self, element: usize) -> &[usize] {
        let n = corner_count(D);
        &self.element_nodes[element * n..(element + 1) * n]
    }

    /// The grid cell of element `element`.
    pub fn element_cell(&self, element: usize) -> usize {
        self.element_cells[element]
    }

    /// The element in grid cell `cell`, if the body fills it.
    pub fn element_of_cell(&self, cell: usize) -> Option<usize> {
        self.cell_elements
            .get(cell)
            .filter(|&&e| e != NO_ELEMENT)
            .map(|&e| e as usize)
    }

    /// The nodes of the mesh (used by some element), increasing.
    pub fn mesh_nodes(&self) -> &[usize] {
        &self.mesh_nodes
    }

    /// The element containing reference position `x` and the parent coordinates of `x` in it,
    /// on the undeformed grid: per axis `ξ_k = 2 (t_k - c_k) - 1` with `t_k = (x_k - lower_k)
    /// / h_k` and `c_k` the cell. `None` if `x` is outside the grid or in a cell that is not an
    /// element.
    pub fn locate(
        &self,
        grid: &GridBasis<D>,
        x: &SVector<f64, D>,
    ) -> Option<(usize, SVector<f64, D>)> {
        let mut cell = [0; D];
        let mut xi = SVector::zeros();
        for k in 0..D {
            let (c, t) = grid.axes[k].locate(x[k]).ok()?;
            cell[k] = c;
            xi[k] = (2.0 * (t - c as f64) - 1.0).clamp(-1.0, 1.0);
        }
        Some((self.element_of_cell(grid.cell_index(cell))?, xi))
    }

    /// The VTK cell kind of the elements: `VTK_LINE`, `VTK_QUAD` or `VTK_HEXAHEDRON`.
    pub fn vtk_kind() -> CellKind {
        match D {
            1 => CellKind::Line,
            2 => CellKind::Quad,
            _ => CellKind::Hexahedron,
        }
    }

    /// Element connectivity in VTK node order (counter-clockwise faces), with nodes numbered
    /// by their position in [`Mesh::mesh_nodes`].
    pub fn vtk_connectivity(&self) -> Vec<u64> {
        // corner order (axis 0 fastest) -> VTK order: swap corners 2 <-> 3 and 6 <-> 7
        const VTK_ORDER: [usize; 8] = [0, 1, 3, 2, 4, 5, 7, 6];
        #[allow(clippy::expect_used, reason = "mesh_nodes holds every element's nodes")]
        let compact = |node: usize| {
            self.mesh_nodes
                .binary_search(&node)
                .expect("an element node is a mesh node") as u64
        };
        (0..self.element_count())
            .flat_map(|e| {
                let nodes = self.element_nodes(e);
                VTK_ORDER[..corner_count(D)]
                    .iter()
                    .map(move |&corner| compact(nodes[corner]))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;
    use nalgebra::{Vector2, Vector3};

    fn grid2() -> GridBasis<2> {
        GridBasis::new(&[0.0, 0.0], &[3.0, 2.0], &[3, 2], BasisKind::Fem).unwrap()
    }

    #[test]
    fn elements_are_the_given_cells_with_their_vertices() {
        let grid = grid2();
        // cells (1, 0) and (0, 1) given out of order and repeated
        let mesh = Mesh::from_cells(&grid, [3, 1, 3]).unwrap();
        assert_eq!(mesh.element_count(), 2);
        assert_eq!((mesh.element_cell(0), mesh.element_cell(1)), (1, 3));
        // vertices numbered i + 4 j: cell (1, 0) has corners 1, 2, 5, 6
        assert_eq!(mesh.element_nodes(0), [1, 2, 5, 6]);
        assert_eq!(mesh.element_nodes(1), [4, 5, 8, 9]);
        assert_eq!(mesh.element_of_cell(3), Some(1));
        assert_eq!(mesh.element_of_cell(0), None);
        assert_eq!(mesh.mesh_nodes(), [1, 2, 4, 5, 6, 8, 9]);
        assert_eq!(mesh.reference_positions[6], Vector2::new(2.0, 1.0));
        // VTK quads counter-clockwise, compact numbering
        assert_eq!(mesh.vtk_connectivity(), [0, 1, 4, 3, 2, 3, 6, 5]);
        assert!(Mesh::from_cells(&grid, [6]).is_err());
        let quadratic = GridBasis::<2>::new(
            &[0.0, 0.0],
            &[3.0, 2.0],
            &[3, 2],
            BasisKind::BSpline { order: 2 },
        )
        .unwrap();
        assert!(
            Mesh::from_cells(&quadratic, [0])
                .unwrap_err()
                .contains("order 1")
        );
    }

    #[test]
    fn locate_gives_element_and_parent_coordinates() {
        let grid = grid2();
        let mesh = Mesh::from_cells(&grid, [1, 3]).unwrap();
        let (e, xi) = mesh.locate(&grid, &Vector2::new(1.25, 0.75)).unwrap();
        assert_eq!(e, 0);
        assert!((xi - Vector2::new(-0.5, 0.5)).norm() < 1e-15);
        assert!(mesh.locate(&grid, &Vector2::new(0.5, 0.5)).is_none());
        assert!(mesh.locate(&grid, &Vector2::new(-0.5, 0.5)).is_none());
        // the element's map takes ξ back to x
        let corners: Vec<_> = mesh
            .element_nodes(e)
            .iter()
            .map(|&n| mesh.reference_positions[n])
            .collect();
        let x = super::super::element::map_to_element(&corners, &xi);
        assert!((x - Vector2::new(1.25, 0.75)).norm() < 1e-15);
    }

    #[test]
    fn hexahedra_have_positive_vtk_orientation() {
        let grid = GridBasis::<3>::new(&[0.0; 3], &[1.0; 3], &[1, 1, 1], BasisKind::Fem).unwrap();
        let mesh = Mesh::from_cells(&grid, [0]).unwrap();
        let c = mesh.vtk_connectivity();
        let p = |i: usize| mesh.reference_positions[mesh.mesh_nodes()[c[i] as usize]];
        // VTK: bottom face 0-1-2-3 counter-clockwise seen from the top face 4-5-6-7
        let normal = (p(1) - p(0)).cross(&(p(3) - p(0)));
        assert!(normal.dot(&(p(4) - p(0))) > 0.0);
        assert_eq!(p(2), Vector3::new(1.0, 1.0, 0.0));
        assert_eq!(p(6), Vector3::new(1.0, 1.0, 1.0));
    }
}
