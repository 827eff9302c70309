//! # impm — an implicit, high-order Material Point Method
//!
//! Quasi-static finite-deformation elasticity (Hencky) solved with a fully implicit Newton
//! method per load step, material points carried through a background grid that is reset after
//! every step, and B-spline bases of any order (Motlagh & Coombs, MPM 2017).
//! See `ARCHITECTURE.md` for the one-screen map; read [`method`] first.
//!
//! * The method: [`method`] (the load step on one page, its stages and hooks), [`control`]
//!   (load-step cutting), [`stages`] (the core systems), [`components`], [`resources`].
//! * Modules: [`plugin`] (the trait every effect, material and user extension implements),
//!   [`effects`] (the built-in ones: materials, loads, constraints, GIMP/CPDI, FEM, ghost
//!   penalty, stress recovery).
//! * Pure kernels: [`basis`], [`material`], [`mechanics`], [`quadrature`], [`solver`],
//!   [`analytic`], [`recovery`], [`interpolation`], [`ghost`], [`fem`], [`parameter`],
//!   [`colouring`] (points into colours for the threaded assembly).
//! * Driver and I/O: [`run`] (build and drive a simulation), [`records`] (summary.json),
//!   [`checkpoint`] (saved states, part by part), [`restart`] (checkpoint files, resuming),
//!   [`explain`] (what a scene runs), [`scene`] (Rhai), [`output`] (VTK), [`study`] (sweeps,
//!   tables and charts).

// No panics on user input or I/O state: errors instead of unwrap/expect on every path the
// command line reaches; the few true invariants carry an #[allow] with their reason.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod analytic;
pub mod basis;
pub mod checkpoint;
pub mod colouring;
pub mod components;
pub mod control;
pub mod distributed;
pub mod effects;
pub mod explain;
pub mod fem;
pub mod ghost;
pub mod interpolation;
pub mod interrupt;
pub mod material;
pub mod mechanics;
pub mod method;
pub mod node_storage;
pub mod output;
pub mod parallel;
pub mod parameter;
pub mod plugin;
pub mod quadrature;
pub mod records;
pub mod recovery;
pub mod resources;
pub mod restart;
pub mod run;
pub mod scene;
pub mod solver;
pub mod stages;
pub mod study;
