//! The core's systems, one file per stage of `method.rs` (which orders them). Thin systems over
//! the pure kernels (`basis`, `mechanics`, `sparse`, `output`); the optional effects' systems
//! live with their modules in `effects/`.
//!
//! | file | stage | system |
//! |------|-------|--------|
//! | `connectivity.rs` | 1 Connectivity | [`evaluate_basis`]: the point basis, the default at `Hook::Basis` |
//! | `dofs.rs` | 2 Dofs | [`number_dofs`]: DOF numbers and the sparsity pattern |
//! | `stress.rs` | 4a StressUpdate | [`update_stress`]: one system per material kind, added by the kinds' modules |
//! | `assembly.rs` | 4b Assembly | [`assemble`]: internal force and consistent tangent |
//! | `newton.rs` | 4c, 4d | [`check_convergence`], [`solve_linear_system`] |
//! | `line_search.rs` | 4c' | [`line_search::judge_iterate`]: accepts or shortens a Newton step (`solver(#{ line_search: true })`) |
//! | `arc_length.rs` | 2–4, 4c, 4d | [`arc_length::correct_load_factor`]: the load factor as an unknown (`solver(#{ control: "arc_length" })`; scheduled by `effects::arc_length` at its hooks) |
//! | `update.rs` | 5 UpdatePoints | [`update_points`]: G2P, paper eq. 10 |
//! | `output.rs` | 6 Output | [`write_particles`], [`write_grid`] (default at `Hook::GridOutput`), [`write_nodes`] |
//! | `reset.rs` | 7 ResetGrid | [`reset_grid`] |

pub mod arc_length;
mod assembly;
mod connectivity;
mod dofs;
pub mod line_search;
mod newton;
pub mod output;
mod reset;
pub mod stress;
mod update;

pub use assembly::{ColouringCache, assemble};
pub use connectivity::evaluate_basis;
pub use dofs::number_dofs;
pub use newton::{DIVERGENCE_GROWTH, check_convergence, solve_linear_system};
pub use output::{write_grid, write_nodes, write_particles};
pub use reset::reset_grid;
pub use stress::{PointHistory, PointMaterial, commit_history, update_stress};
pub use update::update_points;
