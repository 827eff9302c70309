//! Prescribed displacements and supports on material surfaces (`surface_displace(...)`),
//! imposed weakly on the grid functions that support the surface, which need not align with
//! the grid and moves with the material.
//!
//! # Boundary points
//! A condition is declared on a flat piece of the body's boundary (`on:`, the geometry words of
//! `traction(...)`: `scene::seed_surface`), seeded as boundary points s with reference position
//! X_s, reference area A_s (length in 2D) and a host, the nearest material point: the piece is
//! cut into `per_cell` parts per cell crossed, each integrated with the 2-point Gauss rule per
//! edge, so that a piece whose parts lie within knot spans integrates the B-spline products of
//! the boundary terms exactly (quadratic and cubic). Unlike traction points (which average the
//! basis over their carried share: `effects::tractions`), boundary points sample it, so once
//! the material has moved the parts off the knot spans the boundary terms are not exact, and
//! where a body's free side moves into a new column of cells next to the condition a function
//! supported by a sliver of material is decided by that error (docs/boundaries.md, "Free
//! sides": a homogeneous squeeze under a smooth platen with a free side). Shares carried by the
//! host's F were tried and not kept: under the footing's large penetration the host's F
//! distorts them (dips of 14 % against 5 %).
//!
//! A boundary point carries its total displacement u_s = x_s − X_s. At the start of each load
//! step it gets weights N̂_i over active nodes, with which the grid increment is read at the
//! point, Δu_s = Σ_i N̂_i Δu_i: the basis there, N̂_i = N_i(x_s), when every node of its support is
//! active (the usual case: the surface inside or on the face of a cell with material points);
//! otherwise (the surface has left the cells its material points support, e.g. a linear
//! basis's top row of nodes once the material has moved past it) the host's first-order
//! extrapolation, N̂_i = N_i(x_p) + ∇N_i(x_p) · (x_s − x_p) over the host's support (as traction
//! points follow their host). Both sum to one and reproduce linear fields exactly. After the
//! step the point moves with the increment it was held to: x_s += Σ_i N̂_i Δu_i. So u_s is exactly the
//! displacement the condition imposed, and the prescribed value is the **total** displacement
//! of the surface at the load factor, λ ū: the answer does not depend on the number of load
//! steps or on step cuts (unlike a grid-node `displace`, which moves whatever material is at the
//! node at the start of each step).
//!
//! # Weak imposition
//! With P_s the projection onto the constrained components at boundary point s (all: I, rough
//! / no slip; `smooth`: N_s N_sᵀ with N_s the surface's reference outward normal there; listed
//! components: the diagonal of those axes), ū_s its prescribed displacement at load factor 1
//! (the condition's `displacement`, or for `radial` the point's own: "Curved surfaces") and
//! the gap at an iterate
//!
//! ```text
//!   g_s = P_s (u_s^n + Σ_j N̂_j Δu_j − λ ū_s),
//! ```
//!
//! (below P, ū and N stand for the point's P_s, ū_s and N_s),
//!
//! **penalty** adds to the internal force and the tangent (the Hessian of ½ α Σ_s A_s |g_s|²)
//!
//! ```text
//!   f_int,i += α A_s N̂_i g_s,        K_ij += α A_s N̂_i N̂_j P           (symmetric),
//! ```
//!
//! and **Nitsche's method** adds the consistency term, the traction the body carries at the
//! surface, so that the exact solution satisfies the discrete equations for any α (the error
//! does not grow like 1/α):
//!
//! ```text
//!   f_int,i −= N̂_i P T_s,            T_s = τ F⁻ᵀ N A_s = τ_h Δf_h⁻ᵀ m_s,   m_s = F_hⁿ⁻ᵀ N A_s,
//!   K_ij    −= N̂_i P ∂T_s/∂Δu_j      (j in the host's support),
//! ```
//!
//! where T_s is the force on the piece of surface (Nanson: σ n da = τ F⁻ᵀ N dA) from the host's
//! Kirchhoff stress τ_h and F = Δf_h F_hⁿ. T_s has the form of a point's internal force with
//! m_s in place of V0 ∇N, so ∂T_s/∂Δu_j is the host's stiffness block
//! (`TrialState::stiffness(1, Δf⁻ᵀ m_s, Δf⁻ᵀ ∇N_j)`), exact for any material. Without more,
//! this is the non-symmetric "incomplete" variant (`nitsche: "nonsymmetric"`): it needs only
//! the material's first tangent and works with non-symmetric material tangents (plasticity).
//!
//! # Symmetric Nitsche
//! The symmetric variant adds the adjoint term −∫ (A:∇δu · N) · P (u − λ ū) dA. Its exact
//! linearisation with the current tangent A would need ∂A/∂u (the material's second
//! derivative). Here A is frozen for the step: C_j = ∂T_s/∂Δu_j taken with the host's trial
//! state at the step's first iterate (Newton iteration 0 of each attempt; with no prescribed
//! increment at the host's nodes, the committed state), kept in the boundary point:
//!
//! ```text
//!   f_int,j −= C_jᵀ g_s,              K_jk −= C_jᵀ P N̂_k       (j in the host's support),
//! ```
//!
//! bilinear in (δu, g), so the tangent is exact, and consistent: g = 0 at the exact solution,
//! where the term vanishes. Σ_j C_j = 0 (Σ_j ∇N_j = 0), so the term has no resultant and the
//! reaction is unchanged. In small-strain linear elasticity A is constant and this is the
//! classical symmetric Nitsche method. The assembled block is the transpose of the consistency
//! term's where the host's tangent equals the frozen one (at the first iterate, and throughout
//! for a linear material), not otherwise: the run still declares its tangent non-symmetric
//! (`Extension::nonsymmetric_tangent`) and solves with LU. `method: "nitsche"` takes this
//! variant unless a body the condition acts on is of a plastic model
//! (`scene::is_plastic_model`: von_mises, drucker_prager, mohr_coulomb; their tangents change
//! within a step as points yield), then the non-symmetric one; `nitsche: "symmetric"` or
//! `"nonsymmetric"` forces either. `impm check` and the run's log (before step 1,
//! [`imposition_notes`]) name the variant, and the run records it as `NAME_symmetric` (1 or 0)
//! in `summary.json` and `history.csv`.
//!
//! # Nitsche with F-bar
//! When the host is an F-bar point (`body(#{ .., fbar: .. })`, `effects::fbar`) its stress τ̄_h
//! is taken at F̄_h, whose volume change is its group's (the points of its cell, or the patch
//! or projection they average over). T_s then depends on the increments of every node of the
//! group, not only the host's support; with ∂τ̄_h = P_h ∂ln(Δj̄_h/Δj_h) for the volumetric part
//! (`fbar::volume_change_coupling`),
//!
//! ```text
//!   K_ij −= N̂_i P (P_h Δf_h⁻ᵀ m_s) ⊗ (ḡ_j − g_j^h)      (j in the host's group),
//! ```
//!
//! the rank-one term of the F-bar internal force with Δf⁻ᵀ m_s in place of V0 g_i. Without it
//! Newton stalls on nearly incompressible bodies (ν = 0.49: the driven thick cylinder failed
//! its first step). [`couple_nitsche_to_fbar_groups`] puts the pairs into the sparsity
//! pattern. The symmetric variant's adjoint keeps the host's standard block only (it is frozen
//! and consistent either way); with F-bar its tangent is therefore not symmetric at the first
//! iterate either.
//!
//! # Penalty factor
//! α = γ E / h, with E the largest stiffness scale of the scene's materials
//! (`MaterialSpec::stiffness`) and h the smallest cell size: a spring per unit area as stiff as
//! γ cells of the material. Default γ: 1e4 for `penalty` (the gap, the part of the surface
//! traction the material's compliance lets through, is then about σ h / (γ E): 1e-4 of a
//! cell's elastic shortening; relative to a prescribed displacement of 20 % strain over 4 cells
//! that is below 1e-4), and 100 for `nitsche` (it only has to dominate the consistency term
//! for stability, ~E/h per unit area; the accuracy does not depend on it).
//!
//! # Round-off slivers
//! When the material's surface lies on a grid line up to round-off (a homogeneous compression
//! whose top reaches a grid line at the end of a step: 1 − 20 × 0.005 = 0.9 against the line
//! 3 × 0.3 = 0.8999999999999999), the nodes beyond the line are active with a share of the
//! material of the order of the round-off δ ~ 1e-16: weights N_k(x_p) ~ δ² and gradients ~ δ / h
//! (GIMP; smaller for B-splines). Their rows of the system hold a body force ~ σ δ, a
//! stiffness ~ E δ², and the condition's terms through the boundary point's weight N_k(x_s) ~ δ.
//! The body's own term is ∫ σ ∇N_k dv = σ N_k(x_top) A, with x_top the material domain's
//! edge; Nitsche's consistency term is N_k(x_s) σ A, with x_s the boundary point. Both are
//! ~δ, but x_top and x_s agree only to round-off, so their difference, which is not zero at
//! the exact state, is as large as each of them, and the node's increment, ~1 / δ, moves the
//! boundary point (N_k(x_s) Δu_k = O(1)) by about σ / α · O(1): measured Δu_k ~ 1e12 .. 1e13
//! and the boundary points 3.5e-3 off the material in the step where the top left the grid line
//! 0.9 (GIMP, 4 × 4 cells, 40 steps of the docs/boundaries.md compression: step 21), after
//! which the answer stays off (−1.7 % at the end). The exact state is a solution of the
//! equations in exact arithmetic; the method is stable (the trace constant of a node's
//! function over a small cut, ‖N_k‖²_Γ / ‖∇N_k‖²_Ω ~ δ, vanishes with the cut); it is this
//! round-off inconsistency, amplified by the 1 / δ² of the node's rows, that drifts. The
//! penalty has the same sensitivity but at its own gap's scale σ / α (100 times smaller for
//! its default γ = 1e4 than Nitsche's γ = 100), below its 6.5e-5.
//!
//! With a Nitsche condition in the scene, therefore, an active node that every material point
//! supports with a round-off share only, |N_k(x_p)| ≤ 1e-10 and h |∇N_k(x_p)|_∞ ≤ 1e-10 for
//! every p ([`SLIVER`], [`sliver_nodes`]), is made inactive at the start of the step: it gets
//! no DOF and no increment. What the material loses is its share, ≤ 1e-10 of a weight or of a
//! strain; a genuinely small cut (say 1e-4 of a cell: GIMP shares ~1e-3, quadratic B-splines
//! ~1e-8) keeps its node. A boundary point leaves out an inactive node whose weight at it is
//! round-off (≤ 1e-10; [`boundary_weights`]). In a distributed run the processes' supports
//! activate nodes after this (`Hook::Connectivity`), so there a round-off sliver can stay.
//!
//! # Reactions
//! The force the condition exerts on the body, R = Σ_s (P T_s − α A_s g_s) (Nitsche) or
//! −Σ_s α A_s g_s (penalty), at every converged step, with its mean traction R / Σ A_s and the
//! mean displacement of the surface Σ A_s u_s / Σ A_s: measures named after the condition
//! (`NAME_reaction_x`, `NAME_traction_y`, `NAME_displacement_y`, ...) in `summary.json` and
//! `history.csv`.
//!
//! # Separation
//! The condition holds the grid's field at the boundary points, not the material points. Where
//! the material points cannot determine that field at the surface (point-integrated cubic
//! B-splines with 2 × 2 points per cell: the functions at the surface are supported by a sliver
//! of points), the field there satisfies the condition while the material does not follow, and
//! the boundary points move into the material; the reaction is then that of the smaller
//! deformation the material really has (docs/boundaries.md: −42 % in the cubic compression
//! test). After every converged step each condition measures
//!
//! ```text
//!   separation = max_s |P (x̃_s − x_s)|,   x̃_s = x_h + F_h (X_s − X_h)
//! ```
//!
//! the distance of the material's surface x̃_s (the host's first-order extrapolation, exact for
//! homogeneous deformations) from the boundary point x_s, recorded as `NAME_separation`. The
//! reaction's relative error is about the separation over the prescribed displacement; above
//! 0.15 max |P λ ū| (the largest prescribed displacement so far; at least 0.01 h, h the smallest
//! cell size: [`separation_threshold`]) the run warns, once per condition.
//!
//! # The material at the condition
//! The separation reads the material's surface from one point, the host. The material check
//! reads it from the material points under the surface piece (those whose reference position
//! projects onto the piece: not the material beside a footing's edge, where the prescribed
//! displacement does not act), by the least-squares linear fit probes use
//! (`probes::fit_weights`, weights w_k fixed at the start over the 2·2^D nearest such points):
//!
//! ```text
//!   ũ_s = Σ_k w_k (x_k − X_k),   offset = Σ_s A_s |P (ũ_s − λ ū)| / Σ_s A_s,
//!   P̃_s = Σ_k w_k τ_k F_k⁻ᵀ,     material force = Σ_s P̃_s N A_s,
//! ```
//!
//! recorded every step as `NAME_material_displacement_x`, ... (the area-weighted mean ũ),
//! `NAME_material_offset`, `NAME_largest_material_offset` (max_s), `NAME_material_ratio`
//! (offset over [`separation_threshold`]) and `NAME_material_force_x`, ... (the force the
//! material's stress carries across the surface; the reaction's counterpart read from the
//! material). Exact for homogeneous states. A mean offset above the threshold warns (the mean
//! over the condition, not the largest: the fit is poor at a rough footing's edge, where the
//! displacement gradient jumps). What it cannot see: an error of the method inside the body
//! while the material does follow the condition (linear MPM's cell crossing, cubic splines in
//! tension): docs/boundaries.md gives the measured ratios.
//!
//! # Point quadrature: a warning before the run
//! Neither check sees the error of a basis whose quadrature at the material points is wrong
//! inside the body while the material follows the condition. Where that error, measured on
//! the uniaxial-strain block of docs/boundaries.md (4 × 4 cells, 2 × 2 points per cell), is
//! beyond the issue's bounds (reaction within 1 %, material displacement within 0.1 %), a
//! scene that prescribes a non-zero surface displacement gets a warning when it is loaded
//! ([`quadrature_warning`]; `impm check`, the run's log and `summary.json` `warnings`), with
//! the figures and the alternatives: linear MPM (reaction −4.5 % / −14 % in compression /
//! tension), B-splines of order ≥ 3 at the points (cubic tension −2.0 %, order 4 tension
//! −98 %), quadratic B-splines with 1 or 3 points per cell along an axis (material −0.94 %),
//! uGIMP (−2.3 % at 40 steps). Silent: cpGIMP, CPDI, `integration: "domain"` (exact),
//! quadratic B-splines with 2, 4, 5 or 6 points per cell (within 0.05 % at 5 steps).
//!
//! # Curved surfaces: `on: arc(..)` and `radial`
//! In 2D `on:` also takes an `arc(#{ centre, radius, from, to })` (`effects::pressure`). It is
//! cut into `per_cell` equal parts per cell of its length (at least one), each integrated with
//! the 2-point Gauss rule in the angle, so a boundary point at angle θ_s carries the arc length
//! A_s = R Δθ / 2 and the reference normal N_s = ±e_r(θ_s), e_r = (X_s − c)/R, pointing away
//! from its host (the material must lie on one side of the arc, or the scene line is refused).
//! Each point has its own N_s and P_s; the formulas above hold point by point. `radial: u`
//! prescribes the displacement u along each point's radius, away from the centre (u > 0
//! expands a bore), and holds only that component, the tangential motion being free:
//!
//! ```text
//!   ū_s = u e_r(X_s),   P_s = N_s N_sᵀ,   g_s = N_s N_sᵀ (u_s − λ u e_r),
//! ```
//!
//! i.e. the radial displacement of the material surface is λ u and nothing else is held (a
//! smooth, expanding rigid pipe; the inner surface of a thick-walled cylinder moved out). The
//! directions are the reference ones: exact while the surface points move along their radii
//! (the axisymmetric expansion), a small-rotation approximation otherwise. The reaction R_s of
//! each point (below, "Reactions") lies along N_s; the condition records the pressure it takes
//! to hold the surface, the normal force per unit current length (area),
//!
//! ```text
//!   p = −Σ_s R_s · N_s / Σ_s a_s,     a_s = J_h |F_h⁻ᵀ N_s| A_s   (Nanson, the host's F_h),
//! ```
//!
//! as `NAME_pressure` (positive pushing on the body). On a quarter bore the resultant of a
//! uniform p is p (a + u) along each axis; the discrete reaction is not uniform along the arc
//! (the material points represent a curved boundary by whole cells' points), so the axes'
//! reactions and p (a + u) differ by a discretisation error that falls with the cells
//! (docs/plasticity.md, "Benchmark 3"). With every basis the condition is imposed as on a flat
//! piece, and the quadrature warning before the run is the same.
//!
//! # Stages
//!
//! A condition declared in stage k of a staged scene (`scene::stages`) does nothing before
//! stage k (no force, no stiffness, no reaction): its boundary points move with the grid and
//! keep their displacement `s_s = x_s − X_s` and the fitted material one `ũ_s`, so that from
//! stage k's start on the gap is measured from there,
//!
//! ```text
//!   g_s = P (x_s + Δu_h(x_s) − X_s − s_s − λ_k ū),
//! ```
//!
//! with λ_k stage k's own load factor (1 in the stages after it: the settlement held). Its
//! measures (`NAME_displacement_*`, `NAME_material_displacement_*`, ...) are from the stage's
//! start too: the footing pushed after a gravity stage settles from zero. A condition of the
//! first stage has `s_s = ũ_s,0 = 0`: the formulas above. The starts are a checkpoint part
//! ("surface condition starts") in a scene with a condition of a later stage.
//!
//! `until_stage: "s"` releases the condition at the start of the later stage s, with the
//! excavation rule of the grid supports (`effects::grid_constraints`, "Stages"): each boundary
//! point's force on the body at the last converged step of the stage before, R_s (its
//! reaction, below), becomes a load ramped down over stage s and carried by the point, which
//! moves with the material as before its stage,
//!
//! ```text
//!   f_ext,i += (1 − λ_s) N̂_i R_s   in stage s,    nothing after it,
//! ```
//!
//! so that the body starts stage s in equilibrium and is unloaded gradually (elastic soil
//! springs back, plastic soil keeps a permanent set). The condition adds no stiffness from
//! stage s on; its reaction measure is the ramped load in stage s and 0 after it; its
//! displacement measures keep counting from its own start (the rebound); its checks stop.
//! The forces R_s are a checkpoint part ("released surface conditions"), and the convergence
//! criterion keeps its force floor (`declarations::keep_largest_force`).
//!
//! # Decomposed points
//!
//! Under `mpirun --decompose` (`docs/distributed.md`) a material point lives on one process,
//! which moves as the point crosses slabs. Every process holds every boundary point (a few
//! per cell of surface), each keeping its host's and its fit's `PointId`s
//! ([`BoundaryPoint::host_id`]); at every step start, after the exchange of material points,
//! [`follow_boundary_hosts`] links them to the entities this process holds
//! (`Entity::PLACEHOLDER` for another process's). Only the process holding the host finds the
//! point's weights, adds its terms after the assembly (into its shares of `f_int` and `K`,
//! which are summed: once over the processes), adds a released condition's load and moves the
//! point after the step. [`share_boundary_points`] (`Hook::AfterStep`, first; collective, after
//! the failures of the point update are shared) then gathers every held point's position,
//! starts, released force and record ([`BoundaryRecord`], as exact bits) to all processes, so
//! that whichever process holds a host at the next step's start has its boundary point as the
//! host's old process left it, and the conditions' records are taken from all of them in id
//! order ([`record_conditions`], as serially). The material check's fit sums its points'
//! terms on every process over the points it holds and adds them over the processes.
//! `boundary_hosts_changing_process` in summary.json counts the boundary points whose host
//! arrived at another process at a step's start.
//!
//! Two differences from a serial run are handled by refusing, not approximated: a boundary
//! point's support node (weight above [`SLIVER`]) that no point of the host's process touches
//! but a point of another process does would have made the serial run take the basis at the
//! point where this process takes the host's extrapolation; [`refuse_boundary_nodes_elsewhere`]
//! (after the loads, collective, run after a failure too) finds such nodes (`tractions::active_elsewhere`) and fails the
//! step naming them. Nitsche's round-off slivers are found among the points of each process;
//! a sliver made inactive is still a node of its points' supports, which the decomposed grid
//! numbers (`effects::distributed::grid`), so its check fails the step on every process
//! (loudly: the DOF stage's count against the grid's): Nitsche conditions with round-off
//! slivers do not run decomposed yet.
//!
//! Systems: [`find_boundary_supports`] (`Hook::Connectivity`), [`apply_released_conditions`]
//! (`Hook::Loads`, only with `until_stage`), [`assemble_surface_conditions`]
//! (`Hook::AfterAssembly`; in a distributed run a boundary point's terms are added by the
//! process that assembles its host, not marked `AssembledElsewhere`), [`update_boundary_points`] (`Hook::PointUpdate`),
//! [`measure_material_at_conditions`] and [`check_surface_conditions`] (`Hook::AfterStep`).
//! Checkpoint parts (a resumed run continues exactly and does not warn twice): "boundary
//! points" (their positions) and "surface conditions" (per condition whether it has warned
//! and the largest prescribed displacement so far). Symmetric Nitsche's frozen host state is
//! not saved: it is taken again at the first iterate of every step.

use std::collections::{BTreeSet, HashMap};

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};
use rhai::Dynamic;

use super::carried_points::{carried_point, restore_positions, save_positions};
use crate::basis::{BasisKind, BasisScratch, GimpDomain, NodeWeight};
use crate::checkpoint::CheckpointPart;
use crate::components::{
    AssembledElsewhere, DeformationGradient, PointId, Position, ReferencePosition, Support, Trial,
};
use crate::effects::fbar::{FbarCells, FbarSpec, volume_change_coupling};
use crate::mechanics::embed;

use super::declarations::{
    coordinate_range, factor_one, keep_largest_force, released_note, round, until_stage_of,
};
use super::pressure::ArcShape;
use super::probes::{default_neighbours, fit_weights};
use crate::node_storage::NodeVec;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, Newton, Ramp, RunStatus, SolverError, Stage,
    StageClock,
};
use crate::scene::{
    CallSpec, Choice, Kind, Located, ModuleNotes, ModuleWarnings, OptionSpec, Options, PartRule,
    Range, Resolver, SceneApi, SceneSpec, ScriptError, SurfacePointSeed, array_of,
    is_plastic_model, numbers, points_across, seed_surface,
};

/// How a condition is imposed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Imposition {
    Penalty,
    /// Nitsche's method without the adjoint term (module docs): for any material.
    Nitsche,
    /// Nitsche's method with the adjoint term built with the host's tangent frozen at the
    /// step's first iterate (module docs, "Symmetric Nitsche"): for hyperelastic bodies.
    SymmetricNitsche,
}

impl Imposition {
    /// The default dimensionless penalty factor γ (module docs).
    pub fn default_gamma(self) -> f64 {
        match self {
            Imposition::Penalty => 1e4,
            Imposition::Nitsche | Imposition::SymmetricNitsche => 100.0,
        }
    }

    pub fn word(self) -> &'static str {
        match self {
            Imposition::Penalty => "penalty",
            Imposition::Nitsche => "nitsche (non-symmetric)",
            Imposition::SymmetricNitsche => {
                "nitsche (symmetric, adjoint with the step's first tangent)"
            }
        }
    }

    /// Either Nitsche variant: the consistency term is assembled.
    pub fn is_nitsche(self) -> bool {
        self != Imposition::Penalty
    }
}

/// One boundary point of a condition, as resolved from the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct BoundaryPointSpec {
    pub position: Vec<f64>,
    pub area: f64,
    /// The host material point (global point index).
    pub host: usize,
    /// The material points nearest to the reference position and their least-squares linear
    /// fit weights there (`probes::fit_weights`): the material's displacement and stress at the
    /// boundary point (module docs, "The material at the condition").
    pub fit: Vec<(usize, f64)>,
    /// The reference outward unit normal N_s (a flat piece's own; on an arc the radial
    /// direction, away from the material).
    pub normal: Vec<f64>,
    /// The projection P_s onto the constrained components, D x D row by row (module docs).
    pub projection: Vec<f64>,
    /// The prescribed total displacement ū_s at load factor 1 (a flat piece's `displacement`;
    /// `radial: u` on an arc: u e_r(X_s)).
    pub displacement: Vec<f64>,
}

/// One `surface_displace(...)`, resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceConditionSpec {
    /// Names its measures (`NAME_reaction_x`, ...).
    pub name: String,
    /// Line of the declaring call, for messages and `impm check`.
    pub line: Option<usize>,
    pub points: Vec<BoundaryPointSpec>,
    /// The prescribed total displacement at load factor 1 (one entry per axis; zero with
    /// `radial`, whose points have their own: [`BoundaryPointSpec::displacement`]).
    pub displacement: Vec<f64>,
    pub imposition: Imposition,
    /// α = γ E / h (force per unit area per unit gap).
    pub penalty: f64,
    /// Which components, in words, for `impm check` ("all", "normal", "`[1]`").
    pub components: String,
    /// h: the smallest cell size of the grid (the floor of the separation check).
    pub cell: f64,
    /// The stage the condition belongs to (`scene::stages`; 0 without stages): it acts from
    /// that stage's start on and prescribes the displacement from there (module docs,
    /// "Stages").
    pub stage: usize,
    /// `until_stage`: the stage whose start releases it (module docs, "Stages").
    pub until: Option<usize>,
    /// `radial: u` on an arc: the prescribed radial displacement u at load factor 1 and the
    /// arc's centre (module docs, "Curved surfaces"); `None` for the other conditions.
    pub radial: Option<(f64, Vec<f64>)>,
}

impl SurfaceConditionSpec {
    /// Σ A_s.
    pub fn area(&self) -> f64 {
        self.points.iter().map(|p| p.area).sum()
    }
}

/// The scene's surface conditions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceConditions(pub Vec<SurfaceConditionSpec>);

/// `surface_displace(...)` as declared.
#[derive(Clone, Debug)]
struct SurfaceDeclaration {
    /// `on:` the corners of a flat piece (`Some`) or an arc.
    corners: Option<Vec<Vec<f64>>>,
    arc: Option<ArcShape>,
    radial: Option<f64>,
    /// `until_stage`: the name of the stage whose start releases the condition.
    until: Option<String>,
    displacement: Option<Vec<f64>>,
    components: Option<Vec<usize>>,
    smooth: bool,
    imposition: Imposition,
    /// `nitsche: "symmetric"` (true) or `"nonsymmetric"` (false); `None`: by the bodies'
    /// materials (symmetric unless a body under the condition is plastic).
    symmetric: Option<bool>,
    gamma: Option<f64>,
    per_cell: usize,
    name: Option<String>,
}

/// Why surface conditions do not apply to linear FEM.
const NOT_WITH_FEM: &str = "surface conditions act through the background grid's basis; basis \"fem\" has a body-fitted mesh whose nodes move with the body (use fix/displace on its nodes)";

/// A boundary point: an entity of its own that carries a piece of a constrained surface.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct BoundaryPoint<const D: usize> {
    /// Index of its condition.
    pub condition: usize,
    /// Index among all boundary points (checkpoint order).
    pub id: u32,
    pub reference_position: SVector<f64, D>,
    /// Current position (converged, start of the load step).
    pub position: SVector<f64, D>,
    pub area: f64,
    /// The host material point's entity on this process (`Entity::PLACEHOLDER` where another
    /// process holds it: decomposed points, module docs).
    pub host: Entity,
    /// The host's `PointId`: how it is found again after the points are spawned anew or move
    /// between the processes.
    pub host_id: u32,
    /// The material points of the fit at the reference position, with their weights (the
    /// entity `Entity::PLACEHOLDER` for a point another process holds).
    pub fit: Vec<(Entity, f64)>,
    /// The fit's points' `PointId`s, in the order of `fit`.
    pub fit_ids: Vec<u32>,
    /// The active nodes of the basis at `position` with the weights N̂_i (module docs).
    pub weights: Vec<(usize, f64)>,
    /// Symmetric Nitsche: the host's trial state at the step's first iterate, whose tangent
    /// builds the adjoint term for the whole step (module docs, "Symmetric Nitsche").
    pub adjoint_state: Option<crate::mechanics::TrialState<D>>,
    /// The point's displacement `x_s − X_s` and the fitted material displacement ũ_s when its
    /// condition's stage started (zero for a condition of the first stage; module docs,
    /// "Stages").
    pub start: [SVector<f64, D>; 2],
    /// The reference outward unit normal N_s.
    pub normal: SVector<f64, D>,
    /// The projection P_s onto the constrained components.
    pub projection: SMatrix<f64, D, D>,
    /// The prescribed total displacement ū_s at load factor 1.
    pub prescribed: SVector<f64, D>,
    /// The force the point exerted on the body at the last converged step its condition acted
    /// in: in the stage that releases the condition (`until_stage`) the load that replaces it,
    /// ramped down (module docs, "Stages").
    pub released: SVector<f64, D>,
    /// What the point adds to its condition's records at the last converged step
    /// ([`update_boundary_points`], [`record_conditions`]).
    pub record: BoundaryRecord<D>,
}

/// One boundary point's part of its condition's records at a converged step (module docs,
/// "Reactions", "Separation", "Curved surfaces").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundaryRecord<const D: usize> {
    /// R_s: the force the point exerts on the body (in the releasing stage, the ramped load).
    pub reaction: SVector<f64, D>,
    /// |g_s|.
    pub gap: f64,
    /// |P (x̃_s − x_s)|.
    pub separation: f64,
    /// a_s = J_h |F_h⁻ᵀ N_s| A_s, if the host was found.
    pub current_area: Option<f64>,
}

impl<const D: usize> Default for BoundaryRecord<D> {
    fn default() -> Self {
        Self {
            reaction: SVector::zeros(),
            gap: 0.0,
            separation: 0.0,
            current_area: None,
        }
    }
}

/// One condition in the world: what the systems need, and its last reaction.
#[derive(Clone, Debug)]
pub struct SurfaceCondition<const D: usize> {
    /// max_s |P_s ū_s|_∞: the largest prescribed displacement component at load factor 1 (the
    /// scale of the checks).
    pub prescribed_scale: f64,
    pub imposition: Imposition,
    pub penalty: f64,
    pub area: f64,
    /// The force the condition exerted on the body at the last converged step.
    pub reaction: SVector<f64, D>,
    /// Σ A_s u_s / Σ A_s at the last converged step.
    pub mean_displacement: SVector<f64, D>,
    /// max_s |g_s| at the last converged step.
    pub largest_gap: f64,
    /// h: the smallest cell size of the grid.
    pub cell: f64,
    /// max_s |P (x̃_s − x_s)| at the last converged step: how far the material's surface
    /// x̃_s = x_h + F_h (X_s − X_h) (the host's first-order extrapolation) is from the boundary
    /// point x_s, where the condition holds it (module docs, "Separation").
    pub separation: f64,
    /// max |P λ ū| over the steps so far (the scale of the separation check).
    pub largest_prescribed: f64,
    /// Whether the separation check or the material check has warned about this condition
    /// (one warning per condition).
    pub warned: bool,
    /// The material's displacement at the condition, Σ A_s ũ_s / Σ A_s with ũ_s the fitted
    /// material displacement at X_s, at the last converged step.
    pub material_displacement: SVector<f64, D>,
    /// Σ A_s |P (ũ_s − λ ū)| / Σ A_s: how far, on average, the material at the condition is
    /// from the prescribed displacement (a length).
    pub material_offset: f64,
    /// max_s |P (ũ_s − λ ū)|.
    pub largest_material_offset: f64,
    /// The force the material's stress carries across the surface, Σ_s P̃_s N A_s with P̃_s the
    /// fitted first Piola stress at X_s (the reaction's counterpart read from the material).
    pub material_force: SVector<f64, D>,
    /// The stage the condition belongs to: it acts from that stage's start on.
    pub stage: usize,
    /// The stage whose start releases it (`until_stage`), if any.
    pub until: Option<usize>,
    /// Whether the reaction is also recorded as a pressure (`radial` on an arc).
    pub pressure: bool,
    /// The normal force per unit current length (area in 3D) at the last converged step,
    /// p = −Σ_s R_s · N_s / Σ_s a_s (module docs, "Curved surfaces").
    pub mean_pressure: f64,
}

impl<const D: usize> SurfaceCondition<D> {
    /// Whether the condition acts in stage `stage`: from its own stage's start until the start
    /// of the stage that releases it.
    pub fn acts_in(&self, stage: usize) -> bool {
        stage >= self.stage && self.until.is_none_or(|until| stage < until)
    }

    /// Whether stage `stage` releases the condition: its force is then a load ramped down.
    pub fn released_in(&self, stage: usize) -> bool {
        self.until == Some(stage)
    }

    /// Whether stage `stage` is before the condition's own.
    pub fn waits_in(&self, stage: usize) -> bool {
        stage < self.stage
    }

    /// The factor of its prescribed displacement in `step` of stage `stage`: the load factor
    /// in its own stage, 1 after it (`LoadStep::factor_in`).
    pub fn factor(&self, step: &LoadStep, stage: usize) -> f64 {
        step.factor_in(Ramp::staged(false, self.stage), stage)
    }
}

/// The stage of the step (0 without a `CurrentStage`).
fn stage_of(stage: &Option<Res<CurrentStage>>) -> usize {
    stage.as_ref().map_or(0, |s| s.0)
}

/// The conditions of the run, in declaration order.
#[derive(Resource, Clone, Debug, Default)]
pub struct SurfaceConditionSet<const D: usize>(pub Vec<SurfaceCondition<D>>);

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct SurfaceConditionsModule;

fn conditions(spec: &SceneSpec) -> &[SurfaceConditionSpec] {
    spec.part::<SurfaceConditions>().map_or(&[], |c| &c.0)
}

impl Plugin for SurfaceConditionsModule {
    fn name(&self) -> &'static str {
        "surface conditions"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        let choice = |word, meaning| Choice {
            word,
            meaning: Some(meaning),
        };
        api.call(CallSpec::options(
            "surface_displace",
            "prescribes the total displacement (at load factor 1, ramped with it; zero: a support) of a flat piece of a body's surface, or in 2D of an arc (with `radial`: along its radii), that need not follow the grid, imposed weakly (penalty or Nitsche) on the grid functions supporting it through boundary points that move with the material; the reaction, mean traction and mean displacement are recorded every step as NAME_reaction_x, NAME_traction_x, NAME_displacement_x, ... (see docs/boundaries.md)",
            vec![
                OptionSpec::required(
                    "on",
                    Kind::Value {
                        what: "[[..], ..] | arc(#{ .. })",
                    },
                    "the piece of surface: 1D `[[x]]`, 2D a segment `[[x0, y0], [x1, y1]]` or an `arc(#{ centre, radius, from, to })`, 3D a parallelogram `[c0, c1, c2]` (edges c1 − c0, c2 − c0)",
                ),
                OptionSpec::new(
                    "displacement",
                    Kind::Numbers,
                    "the total displacement at load factor 1, one entry per axis (default zero: a support)",
                ),
                OptionSpec::new(
                    "radial",
                    Kind::Number(Range::Any),
                    "on an arc only: the radial displacement u at load factor 1 (positive away from the arc's centre: u > 0 expands a bore), each point moved along its own radius; only the normal (radial) component is held, the tangential motion is free; the reaction is also recorded as NAME_pressure, the normal force per unit current length",
                ),
                OptionSpec::new(
                    "until_stage",
                    Kind::Text,
                    "the (later) stage whose start releases the condition: its force at the end of the stage before is ramped down to zero over that stage, f = (1 − λ) f_end, and it is absent after it (docs/plasticity.md, \"Staged analysis\")",
                ),
                OptionSpec::new(
                    "components",
                    Kind::Wholes { min: 0 },
                    "the constrained axes (0-based; default all of them: rough, no slip)",
                ),
                OptionSpec::new(
                    "smooth",
                    Kind::Flag,
                    "constrain only the component along the surface's normal (a smooth contact; default false)",
                ),
                OptionSpec::new(
                    "method",
                    Kind::Choice(vec![
                        choice("penalty", "a stiff spring per unit area: symmetric, gap ~ σ h / (γ E)"),
                        choice("nitsche", "penalty plus the surface traction: consistent (exact for any γ); with the adjoint term (symmetric) on hyperelastic bodies, without it on plastic ones (option 'nitsche')"),
                    ]),
                    "how the condition is imposed (default \"penalty\")",
                ),
                OptionSpec::new(
                    "nitsche",
                    Kind::Choice(vec![
                        choice("symmetric", "with the adjoint term, built with the host's tangent at the step's first iterate (the tangent is symmetric where the material's tangent has not changed since)"),
                        choice("nonsymmetric", "without the adjoint term: for any material tangent"),
                        choice("auto", "the default: symmetric unless a body the condition acts on is plastic"),
                    ]),
                    "method \"nitsche\" only: force the variant (default: symmetric unless a body the condition acts on is plastic: von_mises, drucker_prager, mohr_coulomb)",
                ),
                OptionSpec::new(
                    "penalty",
                    Kind::Number(Range::Positive),
                    "dimensionless penalty factor γ, α = γ E / h (default 1e4 for penalty, 100 for nitsche)",
                ),
                OptionSpec::new(
                    "per_cell",
                    Kind::Whole {
                        min: 1,
                        max: Some(1000),
                    },
                    "parts per cell crossed, each with 2 Gauss points per edge (default 1)",
                ),
                OptionSpec::new(
                    "name",
                    Kind::Text,
                    "names the recorded quantities (default surface1, surface2, ... in declaration order)",
                ),
            ],
            |builder, options: &Options, at| {
                if options.has("smooth") && options.has("components") {
                    return Err(
                        "give either 'smooth' (the normal component) or 'components', not both"
                            .into(),
                    );
                }
                let imposition = match options.text("method") {
                    Some("nitsche") => Imposition::Nitsche,
                    _ => Imposition::Penalty,
                };
                let variant = options.text("nitsche").filter(|&v| v != "auto");
                if variant.is_some() && imposition != Imposition::Nitsche {
                    return Err("option 'nitsche' chooses a variant of method: \"nitsche\"; give that method or drop the option".into());
                }
                let radial = options.number("radial");
                if radial.is_some()
                    && let Some(other) = ["displacement", "components", "smooth"]
                        .into_iter()
                        .find(|&key| options.has(key))
                {
                    return Err(format!("option 'radial' prescribes the normal (radial) displacement and leaves the tangential motion free: drop option '{other}'"));
                }
                let on = options.value("on").cloned().unwrap_or(Dynamic::UNIT);
                let (corners, arc) = match on.clone().try_cast::<ArcShape>() {
                    Some(arc) => (None, Some(arc)),
                    None => (
                        Some(array_of(
                            &on,
                            "option 'on'",
                            "points like [[0.0, 1.0], [2.0, 1.0]], or an arc(#{ centre, radius, from, to })",
                            numbers,
                        )?),
                        None,
                    ),
                };
                if radial.is_some() && arc.is_none() {
                    return Err("option 'radial' moves the points of an arc along their radii: give on: arc(#{ centre, radius, from, to }) (on a flat piece give 'displacement')".into());
                }
                builder.declare(Located::new(
                    SurfaceDeclaration {
                        corners,
                        arc,
                        radial,
                        until: options.text("until_stage").map(str::to_string),
                        displacement: options.numbers("displacement").map(<[f64]>::to_vec),
                        components: options.wholes("components").map(<[usize]>::to_vec),
                        smooth: options.flag("smooth").unwrap_or(false),
                        imposition,
                        symmetric: variant.map(|v| v == "symmetric"),
                        gamma: options.number("penalty"),
                        per_cell: options.whole("per_cell").unwrap_or(1),
                        name: options.text("name").map(str::to_string),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let over_constrained = over_constraint_warnings(scene);
        let resolved = resolve_conditions(scene)?;
        if !resolved.is_empty() {
            let warning = quadrature_warning(scene.spec, &resolved);
            ModuleWarnings::add(scene.spec, warning);
            ModuleWarnings::add(scene.spec, over_constrained);
            ModuleNotes::add(scene.spec, imposition_notes(&resolved));
            scene.spec.set_part(SurfaceConditions(resolved));
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let lines: Vec<String> = conditions(spec)
            .iter()
            .map(|c| {
                let line = c.line.map(|l| format!("line {l}: ")).unwrap_or_default();
                let (lower, upper) = coordinate_range(c.points.iter().map(|p| &p.position[..]));
                let displacement = match &c.radial {
                    Some((u, centre)) => format!("radial {u} about {centre:?}"),
                    None => format!("{:?}", c.displacement),
                };
                format!(
                    "{line}'{}': {} boundary points, x in {lower:?} .. {upper:?}, area {}, displacement {displacement} {}{}, components {}, {} (α = {:.4e})",
                    c.name,
                    c.points.len(),
                    round(c.area()),
                    factor_one(spec, c.stage),
                    released_note(spec, c.until),
                    c.components,
                    c.imposition.word(),
                    c.penalty
                )
            })
            .collect();
        (!lines.is_empty()).then(|| lines.join("\n"))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        !conditions(spec).is_empty()
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        if !self.applies_to(simulation.spec()) {
            simulation.fail(NOT_WITH_FEM);
            return;
        }
        let specs = conditions(simulation.spec());
        let set = match world_conditions::<D>(specs) {
            Ok(set) => set,
            Err(why) => {
                simulation.fail(why);
                return;
            }
        };
        if let Err(why) = spawn_boundary_points(simulation, specs) {
            simulation.fail(why);
            return;
        }
        if specs.iter().any(|c| c.imposition.is_nitsche()) {
            simulation.nonsymmetric_tangent();
            if simulation.spec().part::<FbarSpec>().is_some() {
                // after the F-bar groups are formed (Hook::Connectivity), before the DOFs
                simulation.add_systems(Hook::Constraints, couple_nitsche_to_fbar_groups::<D>);
            }
        }
        simulation.world().insert_resource(set);
        simulation.world().insert_resource(SurfaceConditionNames(
            specs.iter().map(|c| (c.name.clone(), c.line)).collect(),
        ));
        for (index, condition) in specs.iter().enumerate() {
            add_condition_measures::<D>(simulation, index, condition);
        }
        if specs.iter().any(|c| c.until.is_some()) {
            keep_largest_force(simulation);
            simulation
                .checkpoint(CheckpointPart {
                    name: "released surface conditions",
                    save: save_released::<D>,
                    restore: restore_released::<D>,
                })
                .add_systems(Hook::Loads, apply_released_conditions::<D>);
        }
        if specs.iter().any(|c| c.stage > 0) {
            simulation.checkpoint(CheckpointPart {
                name: "surface condition starts",
                save: save_starts::<D>,
                restore: restore_starts::<D>,
            });
        }
        simulation
            .checkpoint(CheckpointPart {
                name: "boundary points",
                save: save_positions::<D, BoundaryPoint<D>>,
                restore: restore_positions::<D, BoundaryPoint<D>>,
            })
            .checkpoint(CheckpointPart {
                name: "surface conditions",
                save: save_condition_state::<D>,
                restore: restore_condition_state::<D>,
            });
        // decomposed points (module docs): every process holds every boundary point; the
        // host's process handles it, and they are shared after every step
        let decomposed = crate::distributed::decomposed();
        if decomposed {
            simulation.world().init_resource::<BoundaryNodesElsewhere>();
            simulation.world().init_resource::<BoundaryHostsArrived>();
            // the boundary points whose host arrived at the step's start, summed over the
            // processes (collective: every process records the same steps, in the same order)
            let moved = crate::distributed::RUN_MEASURES[6];
            simulation.add_measure(moved, |world, _| {
                let mut arrived = [world.resource::<BoundaryHostsArrived>().0 as f64];
                crate::distributed::sum_over_points(&mut arrived);
                Some(arrived[0])
            });
            simulation.add_systems(Hook::Connectivity, follow_boundary_hosts::<D>);
        }
        simulation
            .add_systems(Hook::Connectivity, find_boundary_supports::<D>)
            .add_systems(Hook::AfterAssembly, assemble_surface_conditions::<D>)
            .add_systems(Hook::PointUpdate, update_boundary_points::<D>);
        if decomposed {
            #[cfg(feature = "mpi")]
            {
                // not in the loads' stage: it runs after a failure too (every process takes
                // part), before the decomposed `f_ext` sum, which shares the failures
                use crate::effects::distributed::decomposition::sum_external_force;
                use crate::method::{StepSchedule, StepSystems};
                let mut schedules = simulation.world().resource_mut::<Schedules>();
                schedules.entry(StepSchedule).add_systems(
                    refuse_boundary_nodes_elsewhere::<D>
                        .after(StepSystems::Loads)
                        .before(sum_external_force::<D>),
                );
            }
            simulation.add_systems(Hook::AfterStep, share_boundary_points::<D>);
        }
        simulation
            .add_systems(Hook::AfterStep, measure_material_at_conditions::<D>)
            .add_systems(Hook::AfterStep, check_surface_conditions::<D>);
    }
}

/// Names of the axes in measure names.
pub const AXES: [&str; 3] = ["x", "y", "z"];

/// `NAME_reaction_x`, `NAME_traction_x`, `NAME_displacement_x`, `NAME_material_displacement_x`,
/// `NAME_material_force_x`, ..., `NAME_separation`, `NAME_material_offset`,
/// `NAME_largest_material_offset` and `NAME_material_ratio` of condition `index`, and for
/// Nitsche's method `NAME_symmetric` (1: the symmetric variant, 0: the non-symmetric one), and
/// with `radial` `NAME_pressure` (module docs, "Curved surfaces").
fn add_condition_measures<const D: usize>(
    simulation: &mut Extension<'_, D>,
    index: usize,
    condition: &SurfaceConditionSpec,
) {
    let (name, imposition) = (condition.name.as_str(), condition.imposition);
    if condition.radial.is_some() {
        simulation.add_measure(format!("{name}_pressure"), move |world, _| {
            let set = world.get_resource::<SurfaceConditionSet<D>>()?;
            Some(set.0.get(index)?.mean_pressure)
        });
    }
    type Quantity<const D: usize> = fn(&SurfaceCondition<D>) -> SVector<f64, D>;
    let quantities: [(&str, Quantity<D>); 5] = [
        ("reaction", |c| c.reaction),
        ("traction", |c| c.reaction / c.area),
        ("displacement", |c| c.mean_displacement),
        ("material_displacement", |c| c.material_displacement),
        ("material_force", |c| c.material_force),
    ];
    for (what, quantity) in quantities {
        for (axis, axis_name) in AXES.iter().enumerate().take(D) {
            let key = format!("{name}_{what}_{axis_name}");
            simulation.add_measure(key, move |world, _| {
                let set = world.get_resource::<SurfaceConditionSet<D>>()?;
                Some(quantity(set.0.get(index)?)[axis])
            });
        }
    }
    type Scalar<const D: usize> = fn(&SurfaceCondition<D>) -> f64;
    let scalars: [(&str, Scalar<D>); 4] = [
        ("separation", |c| c.separation),
        ("material_offset", |c| c.material_offset),
        ("largest_material_offset", |c| c.largest_material_offset),
        ("material_ratio", |c| {
            c.material_offset / separation_threshold(c.largest_prescribed, c.cell)
        }),
    ];
    for (what, quantity) in scalars {
        let key = format!("{name}_{what}");
        simulation.add_measure(key, move |world, _| {
            let set = world.get_resource::<SurfaceConditionSet<D>>()?;
            Some(quantity(set.0.get(index)?))
        });
    }
    if imposition.is_nitsche() {
        // which variant of Nitsche's method the run uses (module docs, "Symmetric Nitsche")
        let symmetric = f64::from(u8::from(imposition == Imposition::SymmetricNitsche));
        simulation.add_measure(format!("{name}_symmetric"), move |_, _| Some(symmetric));
    }
}

/// The conditions' data in the world (vectors and matrices of dimension D).
fn world_conditions<const D: usize>(
    specs: &[SurfaceConditionSpec],
) -> Result<SurfaceConditionSet<D>, String> {
    let mut set = Vec::with_capacity(specs.len());
    for spec in specs {
        let flat = |p: &BoundaryPointSpec| {
            p.projection.len() == D * D && p.displacement.len() == D && p.normal.len() == D
        };
        if spec.displacement.len() != D || !spec.points.iter().all(flat) {
            return Err(format!(
                "surface condition '{}' is not {D}-dimensional",
                spec.name
            ));
        }
        let prescribed_scale = spec
            .points
            .iter()
            .map(|p| {
                (SMatrix::<f64, D, D>::from_row_slice(&p.projection)
                    * SVector::<f64, D>::from_column_slice(&p.displacement))
                .amax()
            })
            .fold(0.0, f64::max);
        set.push(SurfaceCondition {
            prescribed_scale,
            imposition: spec.imposition,
            penalty: spec.penalty,
            area: spec.area(),
            reaction: SVector::zeros(),
            mean_displacement: SVector::zeros(),
            largest_gap: 0.0,
            cell: spec.cell,
            separation: 0.0,
            largest_prescribed: 0.0,
            warned: false,
            material_displacement: SVector::zeros(),
            material_offset: 0.0,
            largest_material_offset: 0.0,
            material_force: SVector::zeros(),
            stage: spec.stage,
            until: spec.until,
            pressure: spec.radial.is_some(),
            mean_pressure: 0.0,
        });
    }
    Ok(SurfaceConditionSet(set))
}

fn spawn_boundary_points<const D: usize>(
    simulation: &mut Extension<'_, D>,
    specs: &[SurfaceConditionSpec],
) -> Result<(), String> {
    let entities = simulation.point_entities();
    let decomposed = crate::distributed::decomposed();
    // a material point's entity; with decomposed points `PLACEHOLDER` for another process's
    let entity = |index: usize, what: &str| match entities.get(index) {
        Some(&entity) if entity != Entity::PLACEHOLDER => Ok(entity),
        _ if decomposed => Ok(Entity::PLACEHOLDER),
        _ => Err(format!("{what} {index} does not exist")),
    };
    let world = simulation.world();
    let mut batch = Vec::new();
    for (condition, spec) in specs.iter().enumerate() {
        for point in &spec.points {
            if point.position.len() != D {
                return Err(format!("boundary point of '{}' not in {D}D", spec.name));
            }
            let host = entity(point.host, "boundary point host")?;
            let position = SVector::from_column_slice(&point.position);
            let fit = point
                .fit
                .iter()
                .map(|&(k, w)| Ok((entity(k, "material point of a fit")?, w)))
                .collect::<Result<Vec<_>, String>>()?;
            batch.push(BoundaryPoint::<D> {
                fit,
                fit_ids: point.fit.iter().map(|&(k, _)| k as u32).collect(),
                normal: SVector::from_column_slice(&point.normal),
                projection: SMatrix::from_row_slice(&point.projection),
                prescribed: SVector::from_column_slice(&point.displacement),
                released: SVector::zeros(),
                record: BoundaryRecord::default(),
                condition,
                id: batch.len() as u32,
                reference_position: position,
                position,
                area: point.area,
                host,
                host_id: point.host as u32,
                weights: Vec::new(),
                adjoint_state: None,
                start: [SVector::zeros(); 2],
            });
        }
    }
    if let Some(point) = batch.iter().find(|p| {
        p.host != Entity::PLACEHOLDER && world.get::<ReferencePosition<D>>(p.host).is_none()
    }) {
        return Err(format!(
            "boundary point {} has no material point as host",
            point.id
        ));
    }
    world.spawn_batch(batch);
    Ok(())
}

/// Decomposed points (module docs): every process holds every boundary point, and after the
/// step start's exchange of material points (`Hook::Connectivity`, before
/// [`find_boundary_supports`]) links each to its host's and its fit's entities on this process
/// by their `PointId`s (`Entity::PLACEHOLDER` for the points another process holds; a point
/// the exchange moved, or spawned anew, has a new entity).
/// Counts the boundary points whose host arrived at this process ([`BoundaryHostsArrived`]).
pub fn follow_boundary_hosts<const D: usize>(
    material: Query<(Entity, &PointId)>,
    mut points: Query<&mut BoundaryPoint<D>>,
    mut arrived: ResMut<BoundaryHostsArrived>,
) {
    let held: HashMap<u32, Entity> = material.iter().map(|(e, id)| (id.0, e)).collect();
    let entity = |id: &u32| held.get(id).copied().unwrap_or(Entity::PLACEHOLDER);
    arrived.0 = 0;
    for mut point in points.iter_mut() {
        let point = &mut *point;
        let before = point.host;
        point.host = entity(&point.host_id);
        if before == Entity::PLACEHOLDER && point.host != Entity::PLACEHOLDER {
            arrived.0 += 1;
        }
        for ((fitted, _), id) in point.fit.iter_mut().zip(&point.fit_ids) {
            *fitted = entity(id);
        }
    }
}

carried_point!(BoundaryPoint);

/// A node's share of the material below which it is a round-off sliver (module docs,
/// "Round-off slivers"): relative to the largest weight 1 and to 1 / h for gradients.
pub const SLIVER: f64 = 1e-10;

/// The weights N̂_i of a boundary point (module docs): the basis at the point, `support`, when
/// all its nodes with a non-zero value are active (or carry a round-off weight, |N_i| ≤
/// [`SLIVER`], which an inactive round-off sliver node may); else the host's first-order
/// extrapolation to the point, N_i(x_p) + ∇N_i(x_p) · `offset` over the host's support (offset
/// = x_s − x_p). Inactive nodes with a round-off weight are left out of either.
pub fn boundary_weights<const D: usize>(
    support: &[NodeWeight<D>],
    host: &[NodeWeight<D>],
    offset: &SVector<f64, D>,
    active: &(impl std::ops::Index<usize, Output = bool> + ?Sized),
) -> Vec<(usize, f64)> {
    let kept = |node: usize, value: f64| value != 0.0 && (active[node] || value.abs() > SLIVER);
    let supported = support
        .iter()
        .all(|w| w.value == 0.0 || active[w.node] || w.value.abs() <= SLIVER);
    if supported {
        return support
            .iter()
            .filter(|w| kept(w.node, w.value))
            .map(|w| (w.node, w.value))
            .collect();
    }
    host.iter()
        .map(|w| (w.node, w.value + w.gradient.dot(offset)))
        .filter(|&(node, value)| active[node] || value.abs() > SLIVER)
        .collect()
}

/// The active nodes that every material point supports with a round-off share only: for
/// each point p and node i of its support |N_i(x_p)| ≤ [`SLIVER`] and h |∇N_i(x_p)|_∞ ≤
/// [`SLIVER`] (h the smallest cell size). Module docs, "Round-off slivers".
pub fn sliver_nodes<'a, const D: usize>(
    supports: impl Iterator<Item = &'a [NodeWeight<D>]>,
    cell: f64,
    active: &NodeVec<bool>,
) -> Vec<usize> {
    let mut share = NodeVec::new(active.len(), 0.0f64);
    for support in supports {
        for w in support {
            let s = w.value.abs().max(cell * w.gradient.amax());
            share[w.node] = share[w.node].max(s);
        }
    }
    (active.written())
        .filter(|&(i, &active)| active && share[i] <= SLIVER)
        .map(|(i, _)| i)
        .collect()
}

/// Connectivity: the basis at every boundary point, and the nodes its condition couples (its
/// own support, and for Nitsche its host's).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn find_boundary_supports<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    set: Res<SurfaceConditionSet<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<(BasisScratch, Vec<NodeWeight<D>>)>,
    hosts: Query<(&Support<D>, &Position<D>)>,
    mut points: Query<&mut BoundaryPoint<D>>,
    mut elsewhere: Option<ResMut<BoundaryNodesElsewhere>>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let (scratch, support) = &mut *scratch;
    let fields = &mut *fields;
    if let Some(elsewhere) = elsewhere.as_deref_mut() {
        elsewhere.0.clear();
    }
    if let Some(nitsche) = set.0.iter().find(|c| c.imposition.is_nitsche()) {
        // round-off slivers get no DOF (module docs, "Round-off slivers")
        let slivers = sliver_nodes(
            hosts.iter().map(|(s, _)| s.0.as_slice()),
            nitsche.cell,
            &fields.active,
        );
        for node in slivers {
            fields.active[node] = false;
        }
    }
    for mut point in points.iter_mut() {
        if point.host == Entity::PLACEHOLDER {
            // decomposed points: the host's process handles it
            point.weights.clear();
            continue;
        }
        let fail = |why: &str| SolverError::Module {
            step: step.number,
            what: format!(
                "boundary point {} of surface condition {} at {:?} {why}",
                point.id,
                point.condition + 1,
                point.position.iter().copied().collect::<Vec<_>>()
            ),
            recoverable: false,
        };
        let Ok((host, host_position)) = hosts.get(point.host) else {
            status.fail(fail("has lost its host material point"));
            return;
        };
        if grid.0.eval(&point.position, scratch, support).is_err() {
            status.fail(fail("left the background grid"));
            return;
        }
        if let Some(elsewhere) = elsewhere.as_deref_mut() {
            // the nodes that would decide the weights were they active on another process
            let active = &fields.active;
            elsewhere.0.extend(
                (support.iter())
                    .filter(|w| w.value.abs() > SLIVER && !active[w.node])
                    .map(|w| w.node),
            );
        }
        let offset = point.position - host_position.0;
        let weights = boundary_weights(support, &host.0, &offset, &fields.active);
        if weights.is_empty() || weights.iter().any(|(node, _)| !fields.active[*node]) {
            status.fail(fail(
                "is not next to any material point (its host's support is not active); put surface conditions on a body's boundary",
            ));
            return;
        }
        let mut group: Vec<usize> = weights.iter().map(|(node, _)| *node).collect();
        if set.0[point.condition].imposition.is_nitsche() {
            group.extend(host.0.iter().map(|w| w.node));
        }
        fields.couplings.push(group);
        point.weights = weights;
    }
}

/// Decomposed points: the boundary points whose host arrived at this process at the current
/// step's start ([`follow_boundary_hosts`]; `boundary_hosts_changing_process` in summary.json
/// sums them over the processes).
#[derive(Resource, Default)]
pub struct BoundaryHostsArrived(pub usize);

/// Decomposed points: the support nodes of this process's boundary points that no point of
/// this process touches (with a weight above [`SLIVER`]), found at the step start
/// ([`find_boundary_supports`]).
#[derive(Resource, Default)]
pub struct BoundaryNodesElsewhere(pub BTreeSet<usize>);

/// Decomposed points (module docs; after the loads' stage, collective: it runs after a
/// failure too, every process taking part, before the `f_ext` sum shares the failures): a
/// boundary point whose support
/// holds a node that no point of its host's process touches but a point of another process
/// does (`tractions::active_elsewhere`) would have had the basis at its position serially
/// (every node of its support active) and the host's extrapolation here; such a step fails,
/// naming the nodes, rather than give another answer than the serial run.
pub fn refuse_boundary_nodes_elsewhere<const D: usize>(
    step: Res<LoadStep>,
    nodes: Res<BoundaryNodesElsewhere>,
    fields: Res<GridFields<D>>,
    mut status: ResMut<RunStatus>,
) {
    let active = &fields.active;
    let found = super::tractions::active_elsewhere(
        &nodes.0,
        |node| active.get(node).copied().unwrap_or(false),
        crate::distributed::gather_over_points,
        crate::distributed::sum_over_points,
    );
    let what = match found {
        Ok(found) if found.is_empty() => return,
        Ok(found) => format!(
            "the support of a surface condition's boundary point holds grid nodes {:?} that only \
             another process's material points touch: with decomposed points the condition \
             cannot use them (not supported yet); run without --decompose",
            found.iter().take(8).collect::<Vec<_>>()
        ),
        Err(why) => format!("finding the boundary points' nodes on other processes: {why}"),
    };
    status.fail(SolverError::Module {
        step: step.number,
        what,
        recoverable: false,
    });
}

/// With F-bar bodies: the nodes of a Nitsche boundary point couple with every node of its
/// host's F-bar group, whose volume change its traction depends on (module docs, "Nitsche with
/// F-bar"), so the sparsity pattern holds those pairs.
pub fn couple_nitsche_to_fbar_groups<const D: usize>(
    set: Res<SurfaceConditionSet<D>>,
    cells: Option<Res<FbarCells>>,
    mut fields: ResMut<GridFields<D>>,
    points: Query<&BoundaryPoint<D>>,
) {
    let Some(cells) = cells else {
        return;
    };
    for point in points.iter() {
        if !set.0[point.condition].imposition.is_nitsche() {
            continue;
        }
        let Some(&(group, _)) = cells.membership.get(&point.host) else {
            continue;
        };
        let nodes = &cells.groups[group].nodes;
        let mut coupled: Vec<usize> = point.weights.iter().map(|(node, _)| *node).collect();
        coupled.extend(nodes);
        fields.couplings.push(coupled);
    }
}

/// The gap g_s = P_s (u_s^n + Σ N̂_i Δu_i − λ ū_s) of a boundary point.
fn gap<const D: usize>(
    point: &BoundaryPoint<D>,
    increment: &(impl std::ops::Index<usize, Output = SVector<f64, D>> + ?Sized),
    factor: f64,
) -> SVector<f64, D> {
    let mut u = point.position - point.reference_position - point.start[0];
    for &(node, n) in &point.weights {
        u += increment[node] * n;
    }
    point.projection * (u - point.prescribed * factor)
}

/// m_s = F_hⁿ⁻ᵀ N_s A_s of a boundary point (module docs), F_hⁿ its host's committed F.
fn nitsche_vector<const D: usize>(
    point: &BoundaryPoint<D>,
    committed: &DeformationGradient<D>,
) -> SVector<f64, D> {
    let inverse = embed(&committed.0)
        .try_inverse()
        .map(|m| crate::mechanics::block::<D>(&m))
        .unwrap_or_else(SMatrix::identity);
    inverse.transpose() * point.normal * point.area
}

/// The Nitsche traction force T_s = τ_h Δf_h⁻ᵀ m_s of a boundary point (module docs), with
/// the host's trial state; also returns Δf⁻ᵀ m_s.
fn nitsche_traction<const D: usize>(
    point: &BoundaryPoint<D>,
    trial: &Trial<D>,
    committed: &DeformationGradient<D>,
) -> (SVector<f64, D>, SVector<f64, D>) {
    let g_m = trial.0.spatial_gradient(&nitsche_vector(point, committed));
    (trial.0.internal_force(1.0, &g_m), g_m)
}

/// Newton: every condition's contribution to f_int and K (module docs).
#[allow(clippy::type_complexity)]
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn assemble_surface_conditions<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    set: Res<SurfaceConditionSet<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    hosts: Query<(&Support<D>, &Trial<D>, &DeformationGradient<D>)>,
    elsewhere: Query<(), With<AssembledElsewhere>>,
    mut points: Query<&mut BoundaryPoint<D>>,
    fbar: Option<Res<FbarCells>>,
    mut coupling: Local<Vec<(usize, SVector<f64, D>)>>,
) {
    let _timer = clock.time(Stage::Assembly);
    let fields = &mut *fields;
    let first_iterate = newton.iterations == 0;
    let matrix = &mut newton.matrix;
    let stage = stage_of(&stage);
    for mut point in points.iter_mut() {
        let condition = &set.0[point.condition];
        // distributed runs: added by the process that assembles the host (shares are summed);
        // with decomposed points by the process holding it (`PLACEHOLDER` elsewhere)
        let held = point.host != Entity::PLACEHOLDER;
        if !condition.acts_in(stage) || !held || elsewhere.contains(point.host) {
            continue;
        }
        let p = point.projection;
        let alpha_a = condition.penalty * point.area;
        let g = gap(&point, &fields.increment, condition.factor(&step, stage));
        let force = g * alpha_a;
        let penalty_block = p * alpha_a;
        for &(i, n_i) in &point.weights {
            fields.internal_force[i] += force * n_i;
            for &(j, n_j) in &point.weights {
                matrix.add_block(
                    &fields.dofs[i],
                    &fields.dofs[j],
                    &(penalty_block * (n_i * n_j)),
                );
            }
        }
        if !condition.imposition.is_nitsche() {
            continue;
        }
        let Ok((support, trial, committed)) = hosts.get(point.host) else {
            continue;
        };
        let (traction, g_m) = nitsche_traction(&point, trial, committed);
        let projected = p * traction;
        for &(i, n_i) in &point.weights {
            fields.internal_force[i] -= projected * n_i;
        }
        for w in &support.0 {
            let g_j = trial.0.spatial_gradient(&w.gradient);
            let block = p * trial.0.stiffness(1.0, &g_m, &g_j);
            for &(i, n_i) in &point.weights {
                matrix.add_block(&fields.dofs[i], &fields.dofs[w.node], &(block * -n_i));
            }
        }
        // an F-bar host: τ̄_h depends on its group's volume change (module docs, "Nitsche
        // with F-bar")
        let state_of = |e: Entity| hosts.get(e).ok().map(|(s, t, _)| (s, &t.0));
        let coupled = fbar
            .as_deref()
            .and_then(|cells| volume_change_coupling(cells, point.host, state_of, &mut coupling));
        if let Some(projection) = coupled {
            let v = p * projection * g_m;
            for &(j, d_j) in coupling.iter() {
                let block = v * d_j.transpose();
                for &(i, n_i) in &point.weights {
                    matrix.add_block(&fields.dofs[i], &fields.dofs[j], &(block * -n_i));
                }
            }
        }
        if condition.imposition != Imposition::SymmetricNitsche {
            continue;
        }
        // the adjoint term with the host's state at the step's first iterate (module docs,
        // "Symmetric Nitsche"): f_j −= C_jᵀ g, K_jk −= C_jᵀ P N̂_k
        if first_iterate || point.adjoint_state.is_none() {
            point.adjoint_state = Some(trial.0.clone());
        }
        let Some(frozen) = point.adjoint_state.as_ref() else {
            continue;
        };
        let a_m = frozen.spatial_gradient(&nitsche_vector(&point, committed));
        for w in &support.0 {
            let c_t = frozen
                .stiffness(1.0, &a_m, &frozen.spatial_gradient(&w.gradient))
                .transpose();
            fields.internal_force[w.node] -= c_t * g;
            let block = c_t * p;
            for &(k, n_k) in &point.weights {
                matrix.add_block(&fields.dofs[w.node], &fields.dofs[k], &(block * -n_k));
            }
        }
    }
}

/// After a converged step: each boundary point's part of its condition's records (its
/// reaction, gap, and for `radial` its current area: [`BoundaryRecord`]), then the point moves
/// with the increment it was held to, and how far the material's surface is from it
/// ([`SurfaceCondition::separation`]); then each condition's reaction, mean displacement,
/// largest gap and separation (and for `radial` its pressure) from its points
/// ([`record_conditions`]; with decomposed points after the points of every process are
/// shared, [`share_boundary_points`]). In the stage that releases a condition its reaction is
/// the ramped load that replaces it (module docs, "Stages").
pub fn update_boundary_points<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    fields: Res<GridFields<D>>,
    mut set: ResMut<SurfaceConditionSet<D>>,
    hosts: Query<(
        &Trial<D>,
        &DeformationGradient<D>,
        &Position<D>,
        &ReferencePosition<D>,
    )>,
    mut points: Query<&mut BoundaryPoint<D>>,
) {
    let stage = stage_of(&stage);
    for mut point in points.iter_mut() {
        if point.host == Entity::PLACEHOLDER {
            continue; // decomposed points: another process's (shared after the step)
        }
        let condition = &set.0[point.condition];
        let acts = condition.acts_in(stage);
        let g = gap(&point, &fields.increment, condition.factor(&step, stage));
        let host = hosts.get(point.host).ok();
        let mut reaction = SVector::zeros();
        if acts {
            reaction = -g * (condition.penalty * point.area);
            if condition.imposition.is_nitsche()
                && let Some((trial, ..)) = host
            {
                // the host's F was just committed: T_s from the trial state and Fⁿ⁺¹ Δf⁻¹ = Fⁿ
                let previous =
                    DeformationGradient(trial.0.increment_inverse * trial.0.deformation_gradient);
                let (traction, _) = nitsche_traction(&point, trial, &previous);
                reaction += point.projection * traction;
            }
            point.released = reaction;
        } else if condition.released_in(stage) {
            reaction = point.released * (1.0 - step.factor);
        }
        let mut du = SVector::<f64, D>::zeros();
        for &(node, n) in &point.weights {
            du += fields.increment[node] * n;
        }
        point.position += du;
        if condition.waits_in(stage) {
            // its stage has not started: it will prescribe the displacement from here
            point.start[0] = point.position - point.reference_position;
        }
        let mut record = BoundaryRecord {
            reaction,
            gap: g.norm(),
            ..BoundaryRecord::default()
        };
        if let Some((_, f, x, reference)) = host {
            if acts {
                let surface = x.0 + f.0 * (point.reference_position - reference.0);
                record.separation = (point.projection * (surface - point.position)).amax();
            }
            if condition.pressure {
                record.current_area = Some(current_area(&f.0, &point.normal, point.area));
            }
        }
        point.record = record;
    }
    if !crate::distributed::decomposed() {
        record_conditions(&mut set, stage, points.iter());
    }
}

/// Each condition's reaction, mean displacement, largest gap and separation, and for `radial`
/// its pressure, from its boundary points' records ([`BoundaryRecord`]), taken in id order
/// (module docs, "Reactions", "Separation", "Curved surfaces"). A condition whose stage has
/// not started records nothing.
pub fn record_conditions<'a, const D: usize>(
    set: &mut SurfaceConditionSet<D>,
    stage: usize,
    points: impl Iterator<Item = &'a BoundaryPoint<D>>,
) {
    for condition in set.0.iter_mut() {
        condition.reaction = SVector::zeros();
        condition.mean_displacement = SVector::zeros();
        condition.largest_gap = 0.0;
        condition.separation = 0.0;
        condition.mean_pressure = 0.0;
    }
    let mut points: Vec<&BoundaryPoint<D>> = points.collect();
    points.sort_by_key(|point| point.id);
    // per condition: Σ_s a_s (the current length or area) and Σ_s −R_s · N_s
    let mut normal_force = vec![(0.0, 0.0); set.0.len()];
    for point in points {
        let condition = &mut set.0[point.condition];
        if condition.waits_in(stage) {
            continue;
        }
        let record = &point.record;
        if condition.pressure
            && let Some(area) = record.current_area
        {
            let sums = &mut normal_force[point.condition];
            sums.0 += area;
            sums.1 -= record.reaction.dot(&point.normal);
        }
        condition.reaction += record.reaction;
        condition.mean_displacement +=
            (point.position - point.reference_position - point.start[0]) * point.area;
        if condition.acts_in(stage) {
            condition.largest_gap = condition.largest_gap.max(record.gap);
        }
        condition.separation = condition.separation.max(record.separation);
    }
    for (condition, (area, force)) in set.0.iter_mut().zip(normal_force) {
        condition.mean_displacement /= condition.area;
        if condition.pressure && area > 0.0 {
            condition.mean_pressure = force / area;
        }
    }
}

/// Numbers per boundary point shared by [`share_boundary_points`]: id; position, start, the
/// released force, the reaction; gap, separation, whether the current area is known, the area.
const fn shared_length(d: usize) -> usize {
    1 + 4 * d + 4
}

/// Decomposed points (module docs; `Hook::AfterStep`, first, collective): the boundary points
/// of every process after the point update (their positions, starts, released forces and
/// records, as exact bits) gathered to all, so that every process holds every boundary point
/// as its host's process left it (a host may be on another process at the next step's start),
/// then the conditions' records from all of them ([`record_conditions`]), the same on every
/// process.
pub fn share_boundary_points<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut set: ResMut<SurfaceConditionSet<D>>,
    mut status: ResMut<RunStatus>,
    mut points: Query<&mut BoundaryPoint<D>>,
) {
    let mut rows = Vec::new();
    for point in points.iter().filter(|p| p.host != Entity::PLACEHOLDER) {
        let r = &point.record;
        rows.push(u64::from(point.id));
        for vector in [
            &point.position,
            &point.start[0],
            &point.released,
            &r.reaction,
        ] {
            rows.extend(vector.iter().map(|c| c.to_bits()));
        }
        rows.extend([r.gap, r.separation].map(f64::to_bits));
        rows.push(u64::from(r.current_area.is_some()));
        rows.push(r.current_area.unwrap_or(0.0).to_bits());
    }
    let length = shared_length(D);
    let count = points.iter().len();
    let all = crate::distributed::gather_over_points(&rows).and_then(|all| {
        if all.len() == count * length {
            Ok(all)
        } else {
            Err(format!(
                "{} numbers for {count} boundary points of {length} numbers",
                all.len()
            ))
        }
    });
    let all = match all {
        Ok(all) => all,
        Err(why) => {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!("sharing the boundary points between the processes: {why}"),
                recoverable: false,
            });
            return;
        }
    };
    let by_id: HashMap<u32, &[u64]> = all
        .chunks_exact(length)
        .map(|row| (row[0] as u32, &row[1..]))
        .collect();
    let vector = |bits: &[u64]| SVector::<f64, D>::from_fn(|a, _| f64::from_bits(bits[a]));
    for mut point in points.iter_mut() {
        let Some(row) = by_id.get(&point.id) else {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!("boundary point {} is held by no process", point.id),
                recoverable: false,
            });
            return;
        };
        point.position = vector(row);
        point.start[0] = vector(&row[D..]);
        point.released = vector(&row[2 * D..]);
        point.record = BoundaryRecord {
            reaction: vector(&row[3 * D..]),
            gap: f64::from_bits(row[4 * D]),
            separation: f64::from_bits(row[4 * D + 1]),
            current_area: (row[4 * D + 2] != 0).then(|| f64::from_bits(row[4 * D + 3])),
        };
    }
    let stage = stage_of(&stage);
    record_conditions(&mut set, stage, points.iter());
}

/// The current area (length in 2D) a_s = J |F⁻ᵀ N| A of a boundary point's piece of surface
/// (Nanson's formula with its host's F; module docs, "Curved surfaces").
pub fn current_area<const D: usize>(
    f: &SMatrix<f64, D, D>,
    normal: &SVector<f64, D>,
    area: f64,
) -> f64 {
    let full = embed(f);
    let Some(inverse) = full.try_inverse() else {
        return 0.0;
    };
    let inverse = crate::mechanics::block::<D>(&inverse);
    full.determinant() * (inverse.transpose() * normal).norm() * area
}

/// In the stage that releases a condition (`until_stage`): every boundary point's force at the
/// end of the stage before, ramped down, f_ext,i += (1 − λ) N̂_i R_s (module docs, "Stages");
/// the point is carried by the material as before its stage.
pub fn apply_released_conditions<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    set: Res<SurfaceConditionSet<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    elsewhere: Query<(), With<AssembledElsewhere>>,
    points: Query<&BoundaryPoint<D>>,
) {
    let _timer = clock.time(Stage::Loads);
    let stage = stage_of(&stage);
    let ramp = 1.0 - step.factor;
    for point in points.iter() {
        // distributed runs: added by the process that assembles the host, as its terms were
        // (with decomposed points, that holds it)
        let held = point.host != Entity::PLACEHOLDER;
        if !set.0[point.condition].released_in(stage) || !held || elsewhere.contains(point.host) {
            continue;
        }
        for &(node, n) in &point.weights {
            fields.external_force[node] += point.released * (ramp * n);
        }
    }
}

/// Every boundary point's released force (`BoundaryPoint::released`), in `id` order.
fn save_released<const D: usize>(world: &mut World) -> Vec<f64> {
    let mut query = world.query::<&BoundaryPoint<D>>();
    let mut rows: Vec<&BoundaryPoint<D>> = query.iter(world).collect();
    rows.sort_by_key(|point| point.id);
    rows.iter()
        .flat_map(|point| point.released.iter().copied())
        .collect()
}

/// Restores what [`save_released`] saved.
fn restore_released<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut query = world.query::<&mut BoundaryPoint<D>>();
    let count = query.iter(world).len();
    let records: Vec<&[f64]> = crate::checkpoint::records(values, D, count)?.collect();
    for mut point in query.iter_mut(world) {
        let record = records
            .get(point.id as usize)
            .ok_or_else(|| format!("no released force saved for boundary point {}", point.id))?;
        point.released = SVector::from_column_slice(record);
    }
    Ok(())
}

/// What a resumed run needs of the conditions besides their points (a `CheckpointPart::save`):
/// per condition whether it has warned (a resumed run does not warn twice) and the largest
/// prescribed displacement so far (the scale of its checks), in declaration order.
fn save_condition_state<const D: usize>(world: &mut World) -> Vec<f64> {
    world
        .get_resource::<SurfaceConditionSet<D>>()
        .map_or_else(Vec::new, |set| {
            set.0
                .iter()
                .flat_map(|c| [f64::from(u8::from(c.warned)), c.largest_prescribed])
                .collect()
        })
}

/// Restores what [`save_condition_state`] saved (a `CheckpointPart::restore`).
fn restore_condition_state<const D: usize>(
    world: &mut World,
    values: &[f64],
) -> Result<(), String> {
    let mut set = world
        .get_resource_mut::<SurfaceConditionSet<D>>()
        .ok_or("the run has no surface conditions")?;
    if values.len() != 2 * set.0.len() {
        return Err(format!(
            "{} values saved for {} conditions (2 each)",
            values.len(),
            set.0.len()
        ));
    }
    for (condition, saved) in set.0.iter_mut().zip(values.chunks_exact(2)) {
        condition.warned = saved[0] != 0.0;
        condition.largest_prescribed = saved[1];
    }
    Ok(())
}

/// Every boundary point's starts `s_s`, `ũ_s` (module docs, "Stages"), in `id` order.
fn save_starts<const D: usize>(world: &mut World) -> Vec<f64> {
    let mut query = world.query::<&BoundaryPoint<D>>();
    let mut rows: Vec<&BoundaryPoint<D>> = query.iter(world).collect();
    rows.sort_by_key(|point| point.id);
    rows.iter()
        .flat_map(|point| point.start.iter().flat_map(|v| v.iter().copied()))
        .collect()
}

/// Restores what [`save_starts`] saved.
fn restore_starts<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut query = world.query::<&mut BoundaryPoint<D>>();
    let count = query.iter(world).len();
    let records: Vec<&[f64]> = crate::checkpoint::records(values, 2 * D, count)?.collect();
    for mut point in query.iter_mut(world) {
        let record = records
            .get(point.id as usize)
            .ok_or_else(|| format!("no start saved for boundary point {}", point.id))?;
        point.start = [
            SVector::from_column_slice(&record[..D]),
            SVector::from_column_slice(&record[D..]),
        ];
    }
    Ok(())
}

/// Threshold of [`check_surface_conditions`]: the fraction of the largest prescribed
/// displacement so far, max |P λ ū| (docs/boundaries.md).
pub const SEPARATION_TOLERANCE: f64 = 0.15;

/// Floor of the threshold of [`check_surface_conditions`], in cells (a support, ū = 0, and
/// the first small steps).
pub const SEPARATION_FLOOR: f64 = 0.01;

/// The separation above which [`check_surface_conditions`] warns: [`SEPARATION_TOLERANCE`]
/// times the largest prescribed displacement so far, at least [`SEPARATION_FLOOR`] cells.
pub fn separation_threshold(largest_prescribed: f64, cell: f64) -> f64 {
    (SEPARATION_TOLERANCE * largest_prescribed).max(SEPARATION_FLOOR * cell)
}

/// After a converged step: the material at every condition (module docs, "The material at the
/// condition"): at each boundary point's reference position X_s the fitted material
/// displacement ũ_s = Σ_k w_k (x_k − X_k) and first Piola stress P̃_s = Σ_k w_k τ_k F_k⁻ᵀ, then
/// per condition the mean material displacement, the mean and largest offset |P (ũ_s − λ ū)|
/// and the force the material's stress carries across the surface, Σ_s P̃_s N A_s.
pub fn measure_material_at_conditions<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut set: ResMut<SurfaceConditionSet<D>>,
    material: Query<(&Position<D>, &ReferencePosition<D>, &Trial<D>)>,
    mut points: Query<&mut BoundaryPoint<D>>,
) {
    let stage = stage_of(&stage);
    for condition in set.0.iter_mut() {
        condition.material_displacement = SVector::zeros();
        condition.material_offset = 0.0;
        condition.largest_material_offset = 0.0;
        condition.material_force = SVector::zeros();
    }
    // per boundary point (in the query's order, the same on every process: each holds every
    // boundary point) ũ_s and P̃_s over the fit's points this process holds, summed over the
    // processes with decomposed points (a fit's points may be on several)
    let mut fitted: Vec<f64> = Vec::with_capacity(points.iter().len() * (D + D * D));
    for point in points.iter() {
        let mut u = SVector::<f64, D>::zeros();
        let mut piola = SMatrix::<f64, D, D>::zeros();
        for &(entity, w) in &point.fit {
            let Ok((x, reference, trial)) = material.get(entity) else {
                continue;
            };
            u += (x.0 - reference.0) * w;
            let inverse = trial
                .0
                .deformation_gradient
                .try_inverse()
                .unwrap_or_else(SMatrix::identity);
            piola += crate::mechanics::block::<D>(&trial.0.kirchhoff) * inverse.transpose() * w;
        }
        fitted.extend(u.iter().chain(piola.iter()));
    }
    crate::distributed::sum_over_points(&mut fitted);
    for (mut point, values) in points.iter_mut().zip(fitted.chunks_exact(D + D * D)) {
        let u = SVector::<f64, D>::from_column_slice(&values[..D]);
        let piola = SMatrix::<f64, D, D>::from_column_slice(&values[D..]);
        let condition = &mut set.0[point.condition];
        if condition.waits_in(stage) {
            point.start[1] = u;
            continue;
        }
        let u = u - point.start[1];
        condition.material_displacement += u * point.area;
        condition.material_force += piola * point.normal * point.area;
        if !condition.acts_in(stage) {
            continue; // released: nothing is prescribed
        }
        let factor = condition.factor(&step, stage);
        let offset = (point.projection * (u - point.prescribed * factor)).norm();
        condition.material_offset += offset * point.area;
        condition.largest_material_offset = condition.largest_material_offset.max(offset);
    }
    for condition in set.0.iter_mut() {
        condition.material_displacement /= condition.area;
        condition.material_offset /= condition.area;
    }
}

/// After a converged step and [`measure_material_at_conditions`]: is the material where the
/// condition holds it (the separation), and does it have the prescribed displacement (the
/// material check)? Both against [`separation_threshold`], which scales with the largest
/// prescribed displacement so far, max |P λ ū|.
///
/// The condition acts on the grid's displacement field at the boundary points; where the
/// material points cannot determine that field at the surface (point-integrated B-splines of
/// high order with few points per cell: the functions at the surface are supported by a sliver
/// of points), the field there can satisfy the condition while the material does not follow,
/// and the boundary points move through the material: the reaction is then that of the
/// smaller deformation the material really has (its relative error is about the separation
/// over the prescribed displacement). A [`SurfaceCondition::separation`] or a mean material
/// offset [`SurfaceCondition::material_offset`] above the threshold is a warning, once per
/// condition (whichever check fires first), in the log and in `summary.json`; the ratio of the
/// material offset to the threshold is recorded every step (`NAME_material_ratio`).
pub fn check_surface_conditions<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    names: Res<SurfaceConditionNames>,
    mut set: ResMut<SurfaceConditionSet<D>>,
    mut warnings: ResMut<crate::resources::Warnings>,
) {
    let stage = stage_of(&stage);
    for (index, condition) in set.0.iter_mut().enumerate() {
        if !condition.acts_in(stage) {
            continue;
        }
        let prescribed = condition.prescribed_scale * condition.factor(&step, stage).abs();
        condition.largest_prescribed = condition.largest_prescribed.max(prescribed);
        let threshold = separation_threshold(condition.largest_prescribed, condition.cell);
        let ratio = condition.material_offset / threshold;
        let (what, amount) = if condition.separation > threshold {
            (
                "the material's surface is {} ({of}) away from where the condition holds it: the grid field at the surface satisfies the condition but the material does not follow it",
                condition.separation,
            )
        } else if ratio > 1.0 {
            (
                "the material at the condition is on average {} ({of}) away from the prescribed displacement (read from the material points under the surface by a linear fit)",
                condition.material_offset,
            )
        } else {
            continue;
        };
        if condition.warned {
            continue;
        }
        condition.warned = true;
        let (name, line) = &names.0[index];
        let line = line.map(|l| format!("line {l}: ")).unwrap_or_default();
        let of = if condition.largest_prescribed > 0.0 {
            format!(
                "{:.0} % of the prescribed displacement {}",
                100.0 * amount / condition.largest_prescribed,
                round(condition.largest_prescribed)
            )
        } else {
            format!("{:.3} cells", amount / condition.cell)
        };
        let what = what
            .replacen("{}", &round(amount).to_string(), 1)
            .replacen("{of}", &of, 1);
        warnings.0.push(format!(
            "{line}surface condition '{name}': at step {} (load factor {}) {what}, so the reaction and the achieved displacement are not to be trusted (use more points per cell or a finer grid, integration: \"domain\", GIMP or CPDI, which integrate a homogeneous state exactly, or a lower order; docs/boundaries.md)",
            step.number,
            step.factor,
        ));
    }
}

/// The conditions' names and declaring lines, for messages.
#[derive(Resource, Clone, Debug, Default)]
pub struct SurfaceConditionNames(pub Vec<(String, Option<usize>)>);

/// Why the basis's point quadrature cannot give a prescribed surface displacement's answer to
/// the issue's bounds (module docs, "Point quadrature"), with the figures measured on the
/// uniaxial-strain block; `None` where it can (or nothing is prescribed).
fn quadrature_error(spec: &SceneSpec) -> Option<&'static str> {
    // points per cell along each axis of every body (distinct coordinates over cells spanned)
    let per_cell = || {
        spec.bodies.iter().flat_map(|body| {
            (0..spec.dim()).filter_map(move |axis| {
                points_across(spec, body, axis).map(|(k, cells)| (k as f64 / cells as f64).round())
            })
        })
    };
    match spec.grid.basis {
        BasisKind::Linear | BasisKind::BSpline { order: 1 } => Some(
            "linear MPM integrates at the material points, whose quadrature is wrong once they cross cell boundaries: the reaction is 4.5 % off in compression to 80 % and 14 % off in tension to 120 % (13 % at 40 steps, and 2 % / 4.5 % with 4 x 4 points per cell)",
        ),
        BasisKind::BSpline { order } if order >= 3 => Some(
            "B-splines of order 3 or more integrated at the material points: with cubic splines the reaction is 2.0 % off in tension to 120 % (4.2 % at 40 steps) and the material's displacement at the surface 0.33 % short in compression (1.4 % with 4 x 4 points per cell); order 4 in tension gives a reaction 98 % off",
        ),
        BasisKind::BSpline { order: 2 } if per_cell().any(|k| k == 1.0 || k == 3.0) => Some(
            "quadratic B-splines with 1 or 3 points per cell along an axis: with 3 x 3 points per cell the material's displacement at the surface is 0.94 % short in compression at 5 steps and the reaction 11 % off at 40 steps (1 x 1 fails); with 2, 4, 5 or 6 points per cell it is within 0.05 %",
        ),
        BasisKind::Gimp {
            domain: GimpDomain::Fixed,
        } => Some(
            "uGIMP's domains keep their initial size, so its quadrature is not exact once the body deforms: the reaction is 2.3 % off in compression to 80 % at 40 steps",
        ),
        _ => None,
    }
}

/// One line per Nitsche condition naming the variant it resolved to (the run's log; `impm
/// check` and `NAME_symmetric` in summary.json say it too): "auto" picks by the bodies'
/// materials, so a reader of the log should not have to work it out.
pub fn imposition_notes(conditions: &[SurfaceConditionSpec]) -> Vec<String> {
    conditions
        .iter()
        .filter(|c| c.imposition.is_nitsche())
        .map(|c| {
            let line = c.line.map(|l| format!("line {l}: ")).unwrap_or_default();
            format!(
                "surface conditions {line}'{}' imposed by {}",
                c.name,
                c.imposition.word()
            )
        })
        .collect()
}

/// The warning a scene gets before it runs when it prescribes a surface displacement on a
/// basis whose point quadrature cannot give the answer to 1 % (module docs, "Point
/// quadrature"): the conditions' lines, the measured errors and the alternatives.
pub fn quadrature_warning(spec: &SceneSpec, conditions: &[SurfaceConditionSpec]) -> Option<String> {
    let prescribed: Vec<String> = conditions
        .iter()
        .filter(|c| (c.points.iter()).any(|p| p.displacement.iter().any(|&u| u != 0.0)))
        .map(|c| match c.line {
            Some(line) => format!("line {line}: '{}'", c.name),
            None => format!("'{}'", c.name),
        })
        .collect();
    if prescribed.is_empty() {
        return None;
    }
    let why = quadrature_error(spec)?;
    Some(format!(
        "surface conditions {} prescribe a displacement on basis {}, whose reaction and displacement are not to be trusted to 1 %: {why} (measured on a block in uniaxial strain, docs/boundaries.md), and the run's checks of the condition do not see it (the material follows the condition; the error is the quadrature inside the body); for reactions and load-displacement curves to 1 % use basis \"gimp\" (cpGIMP) or \"cpdi\", B-splines with integration: \"domain\", quadratic B-splines with 2 or 4 points per cell, or basis \"fem\" with a grid-node displace",
        prescribed.join(", "),
        spec.grid.basis
    ))
}

/// A warning per `radial` condition held by a stiff penalty with `per_cell ≥ 2` (four or more
/// boundary points per cell crossed): measured on the thick cylinder driven by its bore
/// (docs/plasticity.md, Benchmark 3, "It is an over-constraint"), two parts per cell with the
/// default γ = 1e4 over-constrain the bore on linear MPM, GIMP and CPDI: its pressure was a
/// saw-tooth 17 % off the finite-strain reference at 8 cells across the wall, rising where it
/// should fall, the elastic range 2.1 % too stiff, and the run said nothing more than the
/// general quadrature warning. One part per cell (the default) or γ ≤ 100 was within 1.1 %.
fn over_constraint_warnings(scene: &Resolver) -> Vec<String> {
    scene
        .declarations::<SurfaceDeclaration>()
        .iter()
        .filter(|d| {
            let d = &d.value;
            d.radial.is_some()
                && d.per_cell >= 2
                && d.imposition == Imposition::Penalty
                && d.gamma.is_none_or(|gamma| gamma > 100.0)
        })
        .map(|d| {
            let line = d.at.line().map_or(String::new(), |l| format!("line {l}: "));
            format!(
                "{line}surface condition{} holds an arc's radial displacement by the penalty with \
                 per_cell: {} ({} boundary points per cell crossed): so many stiff constraints \
                 over-constrain the surface (the thick cylinder driven by its bore: 17 % off the \
                 finite-strain reference at 8 cells across the wall with per_cell: 2, within \
                 0.6 % with 1; docs/plasticity.md, Benchmark 3); use per_cell: 1 (the default) \
                 or a penalty of at most 100",
                d.value
                    .name
                    .as_ref()
                    .map_or(String::new(), |n| format!(" '{n}'")),
                d.value.per_cell,
                2 * d.value.per_cell
            )
        })
        .collect()
}

/// Boundary points of every `surface_displace(...)`, with the condition's projection, normal
/// and penalty factor.
fn resolve_conditions(scene: &Resolver) -> Result<Vec<SurfaceConditionSpec>, ScriptError> {
    let declarations = scene.declarations::<SurfaceDeclaration>();
    if declarations.is_empty() {
        return Ok(Vec::new());
    }
    if !SurfaceConditionsModule.applies_to(scene.spec) {
        return Err(ScriptError::at(
            declarations[0].at,
            format!("surface_displace(...): {NOT_WITH_FEM}"),
        ));
    }
    let grid = &scene.spec.grid;
    let dim = grid.dim();
    let material_points = scene.spec.material_point_positions();
    let stiffness = scene
        .spec
        .materials
        .iter()
        .map(|m| m.stiffness)
        .fold(0.0, f64::max);
    let cell = (0..dim)
        .map(|a| (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64)
        .fold(f64::INFINITY, f64::min);
    let mut resolved: Vec<SurfaceConditionSpec> = Vec::new();
    for (index, declaration) in declarations.iter().enumerate() {
        let d = &declaration.value;
        let fail = |message: String| {
            ScriptError::at(declaration.at, format!("surface_displace(...): {message}"))
        };
        let displacement = d.displacement.clone().unwrap_or(vec![0.0; dim]);
        if displacement.len() != dim {
            return Err(fail(format!(
                "option 'displacement' has {} components but the grid is {dim}-dimensional",
                displacement.len()
            )));
        }
        if let Some(components) = &d.components {
            if components.is_empty() {
                return Err(fail("option 'components' lists no axis".into()));
            }
            if let Some(c) = components.iter().find(|&&c| c >= dim) {
                return Err(fail(format!(
                    "component {c} does not exist, the grid is {dim}-dimensional (components 0..{})",
                    dim - 1
                )));
            }
        }
        // the piece's boundary points with their outward normals, and which material points
        // lie under it (module docs, "The material at the condition"), within LAYER cells
        let (seeded, normals, under): (Vec<SurfacePointSeed>, Vec<Vec<f64>>, Vec<usize>) =
            match (&d.corners, &d.arc) {
                (Some(corners), _) => {
                    let seeded = seed_surface(
                        grid,
                        &material_points,
                        corners,
                        d.per_cell,
                        PartRule::Gauss(2),
                        "boundary points",
                    )
                    .map_err(fail)?;
                    let normal = outward_normal(corners, &seeded, &material_points);
                    let depth = |x: &[f64]| -> f64 {
                        (0..dim)
                            .map(|a| normal[a] * (x[a] - corners[0][a]))
                            .sum::<f64>()
                            .abs()
                    };
                    let under = (0..material_points.len())
                        .filter(|&k| {
                            let x = material_points[k];
                            depth(x) <= LAYER * cell && under_piece(corners, x, 1e-9 * cell)
                        })
                        .collect();
                    (seeded.clone(), vec![normal; seeded.len()], under)
                }
                (None, Some(arc)) => {
                    if dim != 2 {
                        return Err(fail(format!(
                            "an arc is a 2D boundary, the grid is {dim}-dimensional"
                        )));
                    }
                    let (seeded, normals) =
                        seed_arc(grid, &material_points, arc, d.per_cell, cell).map_err(fail)?;
                    let under = (0..material_points.len())
                        .filter(|&k| under_arc(arc, material_points[k], LAYER * cell))
                        .collect();
                    (seeded, normals, under)
                }
                (None, None) => return Err(fail("option 'on' is missing".into())),
            };
        let under_points: Vec<&[f64]> = under.iter().map(|&k| material_points[k]).collect();
        let count = default_neighbours(dim);
        let fit = |at: &[f64]| -> Result<Vec<(usize, f64)>, ScriptError> {
            match fit_weights(&under_points, at, count) {
                Ok(weights) => Ok(weights.into_iter().map(|(k, w)| (under[k], w)).collect()),
                Err(_) => fit_weights(&material_points, at, count)
                    .map_err(|why| fail(format!("boundary point at {at:?}: {why}"))),
            }
        };
        // P_s: the normal component (smooth, radial), the listed axes, or all of them
        let projection = |normal: &[f64]| -> Vec<f64> {
            (0..dim * dim)
                .map(|k| {
                    let (r, c) = (k / dim, k % dim);
                    match (&d.components, d.smooth || d.radial.is_some()) {
                        (_, true) => normal[r] * normal[c],
                        (Some(list), false) => f64::from(u8::from(r == c && list.contains(&r))),
                        (None, false) => f64::from(u8::from(r == c)),
                    }
                })
                .collect()
        };
        let components = match (&d.components, d.smooth, d.radial) {
            (_, _, Some(_)) => "radial (the normal)".to_string(),
            (_, true, _) => "normal".to_string(),
            (Some(list), false, _) => format!("{list:?}"),
            (None, false, _) => "all".to_string(),
        };
        // ū_s: the declared displacement, or u along the radius through X_s
        let prescribed = |position: &[f64]| -> Vec<f64> {
            match (d.radial, &d.arc) {
                (Some(u), Some(arc)) => {
                    let radius = [position[0] - arc.centre[0], position[1] - arc.centre[1]];
                    let length = radius[0].hypot(radius[1]);
                    vec![u * radius[0] / length, u * radius[1] / length]
                }
                _ => displacement.clone(),
            }
        };
        let until = until_stage_of(
            scene.spec,
            "surface_displace",
            d.until.as_deref(),
            declaration.stage,
            declaration.at,
        )?;
        let name = d.name.clone().unwrap_or(format!("surface{}", index + 1));
        if name.is_empty() || name.contains(|c: char| c.is_whitespace() || c == ',') {
            return Err(fail(format!(
                "name {name:?} must be a non-empty word without spaces or commas (it names history.csv columns)"
            )));
        }
        if resolved.iter().any(|c| c.name == name) {
            return Err(fail(format!(
                "name '{name}' is used by another surface condition"
            )));
        }
        let imposition = match (d.imposition, d.symmetric) {
            (Imposition::Nitsche, Some(true)) => Imposition::SymmetricNitsche,
            (Imposition::Nitsche, None) if !hosts_plastic(scene.spec, &seeded) => {
                Imposition::SymmetricNitsche
            }
            (imposition, _) => imposition,
        };
        let gamma = d.gamma.unwrap_or(imposition.default_gamma());
        resolved.push(SurfaceConditionSpec {
            name,
            line: declaration.at.line(),
            points: seeded
                .into_iter()
                .zip(normals)
                .map(|(s, normal)| {
                    let fit = fit(&s.position)?;
                    Ok(BoundaryPointSpec {
                        projection: projection(&normal),
                        displacement: prescribed(&s.position),
                        normal,
                        position: s.position,
                        area: s.area,
                        host: s.host,
                        fit,
                    })
                })
                .collect::<Result<Vec<_>, ScriptError>>()?,
            displacement: if d.radial.is_some() {
                vec![0.0; dim]
            } else {
                displacement
            },
            imposition,
            penalty: gamma * stiffness / cell,
            components,
            cell,
            until,
            radial: d.radial.zip(d.arc.as_ref().map(|arc| arc.centre.to_vec())),
            stage: declaration.stage,
        });
    }
    Ok(resolved)
}

/// Whether a body hosting one of the `seeded` boundary points is of a plastic material
/// (`scene::is_plastic_model`): Nitsche's method then defaults to the non-symmetric variant.
fn hosts_plastic(spec: &SceneSpec, seeded: &[SurfacePointSeed]) -> bool {
    let mut first = 0;
    spec.bodies.iter().any(|body| {
        let range = first..first + body.points.len();
        first = range.end;
        seeded.iter().any(|s| range.contains(&s.host))
            && spec
                .materials
                .get(body.material)
                .is_some_and(|m| is_plastic_model(&m.model))
    })
}

/// The depth, in cells of the smallest size, of the layer of material under a surface piece
/// among which the material check's fit seeks its neighbours (2·2^D points lie within two cells
/// at one point per cell and axis; when the layer does not determine a fit, all material
/// points are searched).
const LAYER: f64 = 3.0;

/// Whether the reference position `x` lies under the surface piece `corners` (its projection
/// onto the piece's line or plane falls within the piece, to `tolerance`): in 1D every
/// position, in 2D 0 ≤ t ≤ 1 for x = c0 + t (c1 − c0) + ..., in 3D 0 ≤ a, b ≤ 1 for
/// x = c0 + a (c1 − c0) + b (c2 − c0) + ... (the edges' Gram system).
fn under_piece(corners: &[Vec<f64>], x: &[f64], tolerance: f64) -> bool {
    let dim = x.len();
    let edge = |k: usize| -> Vec<f64> { (0..dim).map(|a| corners[k][a] - corners[0][a]).collect() };
    let dot = |a: &[f64], b: &[f64]| -> f64 { a.iter().zip(b).map(|(p, q)| p * q).sum() };
    let offset: Vec<f64> = (0..dim).map(|a| x[a] - corners[0][a]).collect();
    let inside = |t: f64, length: f64| t >= -tolerance / length && t <= 1.0 + tolerance / length;
    match dim {
        1 => true,
        2 => {
            let e = edge(1);
            let length2 = dot(&e, &e);
            inside(dot(&offset, &e) / length2, length2.sqrt())
        }
        _ => {
            let (e1, e2) = (edge(1), edge(2));
            let (g11, g12, g22) = (dot(&e1, &e1), dot(&e1, &e2), dot(&e2, &e2));
            let (r1, r2) = (dot(&offset, &e1), dot(&offset, &e2));
            let det = g11 * g22 - g12 * g12;
            let a = (g22 * r1 - g12 * r2) / det;
            let b = (g11 * r2 - g12 * r1) / det;
            inside(a, g11.sqrt()) && inside(b, g22.sqrt())
        }
    }
}

/// The boundary points of an arc (module docs, "Curved surfaces"): `per_cell` equal parts per
/// cell of its length (at least one), each with the 2-point Gauss rule in the angle (weights
/// R Δθ / 2), their hosts (the nearest material points, within a cell) and their outward
/// normals ±e_r, away from the hosts (refused when the material is on both sides).
fn seed_arc(
    grid: &crate::scene::GridSpec,
    material_points: &[&[f64]],
    arc: &ArcShape,
    per_cell: usize,
    cell: f64,
) -> Result<(Vec<SurfacePointSeed>, Vec<Vec<f64>>), String> {
    // two boundary points per part
    let parts = arc.parts(per_cell, cell, crate::scene::MAX_SEED_CANDIDATES / 2)?;
    let step = (arc.to - arc.from) / parts as f64;
    let gauss = 0.5 / 3f64.sqrt();
    let area = 0.5 * arc.radius * step.abs().to_radians();
    let positions: Vec<Vec<f64>> = (0..parts)
        .flat_map(|k| {
            let middle = arc.from + (k as f64 + 0.5) * step;
            [-gauss, gauss].map(|g| arc.point(middle + g * step).to_vec())
        })
        .collect();
    let hosts = super::pressure::arc_hosts(grid, material_points, &positions, cell)?;
    let mut seeded = Vec::with_capacity(positions.len());
    let mut normals = Vec::with_capacity(positions.len());
    let (mut outward, mut inward) = (0, 0);
    for (position, host) in positions.into_iter().zip(hosts) {
        let h = material_points[host];
        let radial = [
            (position[0] - arc.centre[0]) / arc.radius,
            (position[1] - arc.centre[1]) / arc.radius,
        ];
        // outward: from the host towards the surface
        let sign = if radial[0] * (position[0] - h[0]) + radial[1] * (position[1] - h[1]) >= 0.0 {
            outward += 1;
            1.0
        } else {
            inward += 1;
            -1.0
        };
        normals.push(vec![sign * radial[0], sign * radial[1]]);
        seeded.push(SurfacePointSeed {
            position,
            area,
            half_edges: Vec::new(),
            host,
        });
    }
    if outward > 0 && inward > 0 {
        return Err(format!(
            "material points lie on both sides of the arc ({outward} boundary points have their nearest material point inside the circle, {inward} outside): put the arc on a body's boundary"
        ));
    }
    Ok((seeded, normals))
}

/// Whether the reference position `x` lies under the arc: within `layer` of its circle and at
/// an angle between its ends.
fn under_arc(arc: &ArcShape, x: &[f64], layer: f64) -> bool {
    let (dx, dy) = (x[0] - arc.centre[0], x[1] - arc.centre[1]);
    if (dx.hypot(dy) - arc.radius).abs() > layer {
        return false;
    }
    let (low, high) = (arc.from.min(arc.to), arc.from.max(arc.to));
    let angle = dy.atan2(dx).to_degrees();
    let turns = ((low - angle) / 360.0).ceil();
    let tolerance = 1e-9;
    angle + 360.0 * turns <= high + tolerance || angle + 360.0 * (turns - 1.0) >= low - tolerance
}

/// The unit normal of the surface piece (1D: the axis; 2D: the segment turned by 90°; 3D: the
/// cross product of the edges), oriented away from the material: towards the side of the
/// boundary points away from their hosts.
fn outward_normal(
    corners: &[Vec<f64>],
    seeded: &[crate::scene::SurfacePointSeed],
    material_points: &[&[f64]],
) -> Vec<f64> {
    let dim = corners.len();
    let edge = |k: usize| -> Vec<f64> { (0..dim).map(|a| corners[k][a] - corners[0][a]).collect() };
    let mut normal = match dim {
        1 => vec![1.0],
        2 => {
            let e = edge(1);
            vec![e[1], -e[0]]
        }
        _ => {
            let (a, b) = (edge(1), edge(2));
            vec![
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        }
    };
    let length = normal.iter().map(|c| c * c).sum::<f64>().sqrt();
    normal.iter_mut().for_each(|c| *c /= length);
    let away: f64 = seeded
        .iter()
        .map(|s| {
            let host = material_points[s.host];
            (0..dim)
                .map(|a| normal[a] * (s.position[a] - host[a]))
                .sum::<f64>()
        })
        .sum();
    if away < 0.0 {
        normal.iter_mut().for_each(|c| *c = -*c);
    }
    normal
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quarter ring a = 1 ≤ r ≤ b = 2 of points on a 4 × 4 grid of cells 0.5, and its bore.
    fn ring() -> (crate::scene::GridSpec, Vec<Vec<f64>>, ArcShape) {
        let grid = crate::scene::GridSpec {
            lower: vec![0.0, 0.0],
            upper: vec![2.0, 2.0],
            cells: vec![4, 4],
            basis: BasisKind::Linear,
        };
        let points = (0..40)
            .flat_map(|i| {
                (0..40).map(move |j| vec![0.025 + 0.05 * i as f64, 0.025 + 0.05 * j as f64])
            })
            .filter(|x| (1.0..=2.0).contains(&x[0].hypot(x[1])))
            .collect();
        let arc = ArcShape {
            centre: [0.0, 0.0],
            radius: 1.0,
            from: 0.0,
            to: 90.0,
        };
        (grid, points, arc)
    }

    /// The bore's boundary points: 2 per part, `per_cell` parts per cell of arc length; their
    /// lengths sum to the arc's (π/2), their normals point at the centre (away from the wall),
    /// and the 2-point Gauss rule integrates e_r over the arc, ∫ e_r R dθ = R (1, 1), to the
    /// rule's error (8e-7 with 7 parts: (Δθ)⁴ / 270 of each part's).
    #[test]
    fn an_arc_is_seeded_with_gauss_points_and_normals_away_from_the_material() {
        let (grid, points, arc) = ring();
        let refs: Vec<&[f64]> = points.iter().map(Vec::as_slice).collect();
        let (seeded, normals) = seed_arc(&grid, &refs, &arc, 2, 0.5).unwrap();
        assert_eq!(seeded.len(), 2 * 7); // ⌈2 π/2 / 0.5⌉ = 7 parts
        let length: f64 = seeded.iter().map(|s| s.area).sum();
        assert!(
            (length - std::f64::consts::FRAC_PI_2).abs() < 1e-14,
            "{length}"
        );
        let mut resultant = [0.0; 2];
        for (s, n) in seeded.iter().zip(&normals) {
            let r = s.position[0].hypot(s.position[1]);
            assert!((r - 1.0).abs() < 1e-14);
            for a in 0..2 {
                assert!(
                    (n[a] + s.position[a]).abs() < 1e-14,
                    "{n:?} at {:?}",
                    s.position
                );
                resultant[a] -= n[a] * s.area;
            }
        }
        for value in resultant {
            assert!((value - 1.0).abs() < 1e-6, "{resultant:?}");
        }
        // the material outside the arc: the normals turn round
        let outer = ArcShape { radius: 2.0, ..arc };
        let (seeded, normals) = seed_arc(&grid, &refs, &outer, 1, 0.5).unwrap();
        for (s, n) in seeded.iter().zip(&normals) {
            assert!((n[0] - s.position[0] / 2.0).abs() < 1e-14);
        }
    }

    /// Under an arc: within the layer of its circle and between its angles, also across 0°.
    #[test]
    fn under_arc_reads_the_angles_across_zero() {
        let arc = ArcShape {
            centre: [1.0, 1.0],
            radius: 1.0,
            from: 350.0,
            to: 370.0,
        };
        let at = |degrees: f64, r: f64| {
            let t = degrees.to_radians();
            [1.0 + r * t.cos(), 1.0 + r * t.sin()]
        };
        assert!(under_arc(&arc, &at(5.0, 1.1), 0.2));
        assert!(under_arc(&arc, &at(-5.0, 0.9), 0.2));
        assert!(!under_arc(&arc, &at(20.0, 1.0), 0.2));
        assert!(!under_arc(&arc, &at(5.0, 1.3), 0.2));
        let quarter = ArcShape {
            centre: [0.0, 0.0],
            radius: 1.0,
            from: 90.0,
            to: 0.0,
        };
        assert!(under_arc(&quarter, &[0.7, 0.8], 0.2));
        assert!(!under_arc(&quarter, &[-0.1, 1.0], 0.05));
    }

    /// Nanson's a = J |F⁻ᵀ N| A in 2D is the stretched tangent |F t| A (t ⟂ N), for a general
    /// F (stretch, shear, rotation).
    #[test]
    fn the_current_length_is_the_stretched_tangent() {
        let f = SMatrix::<f64, 2, 2>::new(1.3, 0.4, -0.2, 0.8);
        for degrees in [0.0f64, 30.0, 135.0, 250.0] {
            let t = degrees.to_radians();
            let normal = SVector::<f64, 2>::new(t.cos(), t.sin());
            let tangent = SVector::<f64, 2>::new(-t.sin(), t.cos());
            let expected = (f * tangent).norm() * 0.7;
            let area = current_area(&f, &normal, 0.7);
            assert!((area - expected).abs() < 1e-14, "{area} {expected}");
        }
    }
}
