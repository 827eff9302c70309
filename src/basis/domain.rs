//! The particle domain of a point at the start of a load step, per method, and the weights it
//! gives (the kernel of the connectivity stage for GIMP and CPDI).
//!
//! A point seeded with `ppc_k` points per cell along axis k owns the box of half-lengths
//! `lp0_k = h_k / (2 ppc_k)` around it (its share of the cell; of the cell's overlap with the
//! region where a box region cuts the cell, `scene::seeding`); this is its initial domain.
//! At the start of load step n+1 (converged deformation gradient `F = F^n`):
//!
//! | method | domain | weights |
//! |---|---|---|
//! | uGIMP (`gimp: "fixed"`) | box, `l_k = lp0_k` | [`super::gimp`] |
//! | cpGIMP (`gimp: "stretched"`) | box, `l_k = lp0_k F_kk` | [`super::gimp`] |
//! | CPDI1 (`"cpdi"`) | parallelepiped, `r_k = F lp0_k e_k` | [`super::cpdi`] |
//! | B-splines, `integration: "domain"` | box, `l_k = lp0_k F_kk` | [`super::averaged`] |
//!
//! The stretched box follows the diagonal of F, as in contiguous-particle GIMP: for the
//! axis-aligned stretches of a column the boxes of neighbouring points stay contiguous; a
//! rotation or shear is not represented (use CPDI). `F_kk <= 0` would invert the box and is an
//! error.
//!
//! # Frozen weights and the consistent tangent
//!
//! Like the B-spline weights, these are evaluated once per load step from the converged state
//! at its start and held fixed during the Newton iterations (`Support`). Within the step the
//! increment of deformation is `Δf = I + Σ_i Δu_i ⊗ ∇S_ip`, linear in the unknowns with frozen
//! coefficients, exactly as for B-splines, so the tangent of `mechanics` is the exact
//! derivative of the discrete internal force and Newton keeps its quadratic convergence. (The
//! dependence of the domain on F enters only from one step to the next.)

use nalgebra::{SMatrix, SVector};

use super::cpdi::CpdiScratch;
use super::error::DomainError;
use super::grid::{BasisScratch, GridBasis, NodeWeight};
use super::{BasisKind, GimpDomain};

/// Buffers reused by [`eval_point_domain`] (no allocation once warm).
#[derive(Clone, Debug, Default)]
pub struct DomainScratch<const D: usize> {
    basis: BasisScratch,
    cpdi: CpdiScratch<D>,
}

/// cpGIMP half-lengths `l_k = lp0_k F_kk`; an error if some `F_kk` is not positive.
pub fn stretched_half_lengths<const D: usize>(
    deformation_gradient: &SMatrix<f64, D, D>,
    initial_half_lengths: &SVector<f64, D>,
) -> Result<SVector<f64, D>, DomainError> {
    for k in 0..D {
        let stretch = deformation_gradient[(k, k)];
        if !(stretch > 0.0 && stretch.is_finite()) {
            return Err(DomainError::Degenerate(format!(
                "its stretched box domain is inverted: F[{k}][{k}] = {stretch:e} is not positive \
                 (large rotation or shear; use basis \"cpdi\", or B-splines with integration \
                 \"points\")"
            )));
        }
    }
    Ok(initial_half_lengths.component_mul(&deformation_gradient.diagonal()))
}

/// CPDI domain vectors `r_k = F lp0_k e_k`, the columns of `F diag(lp0)`.
pub fn cpdi_vectors<const D: usize>(
    deformation_gradient: &SMatrix<f64, D, D>,
    initial_half_lengths: &SVector<f64, D>,
) -> SMatrix<f64, D, D> {
    deformation_gradient * SMatrix::from_diagonal(initial_half_lengths)
}

/// The weights of a point at `position` with deformation gradient `deformation_gradient` and
/// initial domain half-lengths `initial_half_lengths`, for the grid's method (the domain is
/// ignored for linear and B-spline grids, and for FEM, whose points use the element basis of
/// `stages::element_basis` instead). Fills `out` like [`GridBasis::eval`].
pub fn eval_point_domain<const D: usize>(
    grid: &GridBasis<D>,
    position: &SVector<f64, D>,
    deformation_gradient: &SMatrix<f64, D, D>,
    initial_half_lengths: &SVector<f64, D>,
    scratch: &mut DomainScratch<D>,
    out: &mut Vec<NodeWeight<D>>,
) -> Result<(), DomainError> {
    match grid.kind() {
        BasisKind::Linear | BasisKind::BSpline { .. } | BasisKind::Fem => grid
            .eval(position, &mut scratch.basis, out)
            .map_err(DomainError::Outside),
        BasisKind::Gimp {
            domain: GimpDomain::Fixed,
        } => grid
            .eval_domain_average(position, initial_half_lengths, &mut scratch.basis, out)
            .map_err(DomainError::Outside),
        BasisKind::Gimp {
            domain: GimpDomain::Stretched,
        } => {
            out.clear();
            let half_lengths = stretched_half_lengths(deformation_gradient, initial_half_lengths)?;
            grid.eval_domain_average(position, &half_lengths, &mut scratch.basis, out)
                .map_err(DomainError::Outside)
        }
        BasisKind::BSplineDomain { .. } => {
            out.clear();
            let half_lengths = stretched_half_lengths(deformation_gradient, initial_half_lengths)?;
            grid.eval_domain_average(position, &half_lengths, &mut scratch.basis, out)
                .map_err(DomainError::Outside)
        }
        BasisKind::Cpdi => grid.eval_cpdi(
            position,
            &cpdi_vectors(deformation_gradient, initial_half_lengths),
            &mut scratch.cpdi,
            out,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Vector2};

    fn grid(kind: BasisKind) -> GridBasis<2> {
        GridBasis::new(&[0.0, 0.0], &[4.0, 2.0], &[4, 2], kind).unwrap()
    }

    fn weights(kind: BasisKind, f: &Matrix2<f64>) -> Result<Vec<NodeWeight<2>>, DomainError> {
        let mut out = Vec::new();
        eval_point_domain(
            &grid(kind),
            &Vector2::new(1.6, 0.7),
            f,
            &Vector2::new(0.25, 0.125),
            &mut DomainScratch::default(),
            &mut out,
        )
        .map(|_| out)
    }

    fn stretched() -> BasisKind {
        BasisKind::Gimp {
            domain: GimpDomain::Stretched,
        }
    }

    #[test]
    fn each_method_uses_its_domain() {
        let f = Matrix2::new(1.4, 0.3, -0.1, 0.8);
        let l0 = Vector2::new(0.25, 0.125);
        let x = Vector2::new(1.6, 0.7);
        let expect = |kind: BasisKind, l: Vector2<f64>| {
            let mut out = Vec::new();
            grid(kind)
                .eval_domain_average(&x, &l, &mut BasisScratch::default(), &mut out)
                .unwrap();
            out
        };
        let fixed = BasisKind::Gimp {
            domain: GimpDomain::Fixed,
        };
        assert_eq!(weights(fixed, &f).unwrap(), expect(fixed, l0));
        assert_eq!(
            weights(stretched(), &f).unwrap(),
            expect(stretched(), Vector2::new(0.25 * 1.4, 0.125 * 0.8))
        );
        let mut cpdi = Vec::new();
        grid(BasisKind::Cpdi)
            .eval_cpdi(
                &x,
                &Matrix2::new(1.4 * 0.25, 0.3 * 0.125, -0.1 * 0.25, 0.8 * 0.125),
                &mut CpdiScratch::default(),
                &mut cpdi,
            )
            .unwrap();
        assert_eq!(weights(BasisKind::Cpdi, &f).unwrap(), cpdi);
        // linear grids ignore the domain
        let mut linear = Vec::new();
        grid(BasisKind::Linear)
            .eval(&x, &mut BasisScratch::default(), &mut linear)
            .unwrap();
        assert_eq!(weights(BasisKind::Linear, &f).unwrap(), linear);
    }

    #[test]
    fn inverted_stretched_domain_is_an_error() {
        let f = Matrix2::new(-0.1, 1.0, -1.0, 0.5);
        let error = weights(stretched(), &f).unwrap_err();
        assert!(error.to_string().contains("F[0][0]"), "{error}");
        // CPDI handles the same (admissible, det F > 0) deformation
        assert!(weights(BasisKind::Cpdi, &f).is_ok());
    }
}
