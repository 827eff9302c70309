//! Linear finite elements, updated Lagrangian, on a body-fitted mesh (`basis = "fem"`): the
//! paper's FEM comparator as one method among the MPM variants, through the same material,
//! mechanics kernels, Newton solver, sparse system and output.
//!
//! # The mesh
//!
//! The mesh is the set of background-grid cells the body covers ([`Mesh`]): each such cell is
//! an element (2-node bar in 1D, 4-node quadrilateral in 2D, 8-node hexahedron in 3D) and the
//! mesh nodes are the grid vertices of those cells, so node numbers, DOF numbering,
//! constraints and the grid fields are those of linear MPM on the same grid. Unlike MPM, the
//! nodes are never reset: after a converged step every mesh node moves with the body,
//! `x_i += Δu_i`, so the element geometry is always the current configuration.
//!
//! The scene decides which cells are elements (`scene::fem_seeding`): a cell is an element when
//! the body's region holds at the cell centre, near each corner and at the Gauss points; a
//! region that holds at some of these probes but not all covers the cell only partly and is an
//! error, because FEM needs a body-fitted mesh (a body made of whole grid cells).
//!
//! # Isoparametric elements ([`element`])
//!
//! On the parent element `[-1, 1]^D`, corner `a = b_0 + 2 b_1 + 4 b_2` (`b_k ∈ {0, 1}`) has
//! signs `s_k = 2 b_k - 1` and
//!
//! ```text
//!   N_a(ξ) = Π_k (1 + s_k ξ_k) / 2,     x(ξ) = Σ_a N_a(ξ) x_a,
//!   J = ∂x/∂ξ = Σ_a x_a ⊗ ∇_ξ N_a,      ∇_x N_a = J⁻ᵀ ∇_ξ N_a,      dV = det J dξ.
//! ```
//!
//! # Integration points ([`crate::quadrature`])
//!
//! The body's `ppc` becomes the number of Gauss–Legendre points per direction (1 = element
//! centre, 2 = 2x2(x2), ...): points ξ_g and weights w_g of the n-point rule, exact for
//! polynomials of degree 2n - 1, tensor products in 2D/3D. Integration point p of element e
//! replaces a material point, with a fixed element and parent coordinate ξ_p
//! (`effects::fem_mesh::ElementPoint`) and
//!
//! ```text
//!   X_p = Σ_a N_a(ξ_p) X_a,     V0_p = w_p det J_0(ξ_p),     m_p = ρ0 V0_p,
//! ```
//!
//! with J_0 the reference Jacobian (`diag(h_k / 2)` on the undistorted grid).
//!
//! # The MPM stages are exactly linear FEM
//!
//! Only connectivity changes: at the start of step n+1, `effects::fem_mesh` gives each
//! point the values `N_a(ξ_p)` and the gradients `∇_n N_a = J_n⁻ᵀ ∇_ξ N_a` from the current node
//! positions x^n, in place of the background-grid basis. Everything downstream is unchanged,
//! and is the FEM discretisation:
//!
//! * Geometry: the Jacobian after the increment is
//!   `J_{n+1}(ξ_p) = Σ_a (x_a^n + Δu_a) ⊗ ∇_ξ N_a = Δf J_n(ξ_p)` with the MPM increment of
//!   deformation `Δf = I + Σ_a Δu_a ⊗ ∇_n N_a`. By induction the MPM update `F = Δf F^n` gives
//!   `F = J_{n+1} J_0⁻¹`, the FEM deformation gradient at ξ_p, and `det J_{n+1} = det F det J_0`.
//! * Internal force: `∇_x N_a = J_{n+1}⁻ᵀ ∇_ξ N_a = Δf⁻ᵀ ∇_n N_a = g_a`, the gradient of
//!   `mechanics`, so the FEM integral
//!   `f_int,a = ∫ σ ∇_x N_a dv = Σ_p w_p det J_{n+1} σ_p g_a = Σ_p V0_p τ_p g_a`
//!   is `mechanics::TrialState::internal_force`.
//! * Tangent: the consistent tangent of `mechanics` is the derivative of that internal force
//!   with respect to Δu with the step-start basis held fixed; the FEM internal force depends on
//!   Δu only through the same expression, so it is the FEM tangent (checked against finite
//!   differences of an assembled FEM force in `tests/fem.rs`).
//! * Loads: `f_ext,a = Σ_p m_p b N_a(ξ_p)`, the consistent FEM body force.
//! * Point update (paper eq. 10): `x_p += Σ_a N_a(ξ_p) Δu_a` keeps `x_p = Σ_a N_a(ξ_p) x_a`.
//!
//! The module `effects::fem_mesh` swaps the connectivity system and adds the mesh advance (the
//! nodes move by Δu) while the grid fields are still cleared after each step; the output writes the
//! deformed mesh as `grid_NNNN.vtu` and the integration points as `particles_NNNN.vtu`.

pub mod element;
pub mod mesh;

pub use crate::quadrature::{gauss_legendre, tensor_gauss_rule};
pub use element::{
    DegenerateElement, corner_count, element_jacobian, element_weights, jacobian_determinant,
    map_to_element, shape_function,
};
pub use mesh::Mesh;
