//! # impm — an implicit, high-order Material Point Method
//!
//! Quasi-static finite-deformation elasticity (Hencky) solved with a fully implicit Newton
//! method per load step, material points carried through a background grid that is reset after
//! every step, and B-spline bases of any order (Motlagh & Coombs, MPM 2017).
//! See `ARCHITECTURE.md` for the one-screen map of stages and entities.
//!
//! * Pure kernels: [`basis`], [`material`], [`mechanics`], [`sparse`], [`analytic`],
//!   [`recovery`] (MLS stress recovery), [`fem`] (linear finite elements on a body-fitted
//!   mesh, the paper's FEM comparator).
//! * ECS: [`components`], [`resources`], [`stages`] (systems and schedules).
//! * Driver and I/O: [`simulation`], [`scene`] (Rhai), [`output`] (VTK), [`summary`],
//!   [`study`] (parameter sweeps, tables and charts).
//! * Extension: [`plugin`] (your own systems at named hooks of the schedules).

pub mod analytic;
pub mod basis;
pub mod components;
pub mod fem;
pub mod ghost;
pub mod material;
pub mod mechanics;
pub mod output;
pub mod plugin;
pub mod quadrature;
pub mod recovery;
pub mod resources;
pub mod scene;
pub mod simulation;
pub mod sparse;
pub mod stages;
pub mod study;
pub mod summary;
