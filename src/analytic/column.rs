//! The elastic column loaded by its own weight (paper section 3, eqs. 11-15).
//!
//! # Problem
//!
//! A column of reference height `L0` and reference density `rho0` stands on a fixed base at
//! `X = 0` (`X` is the reference coordinate along the column) and is loaded by a body force
//! `b_f` per unit mass along the column axis (`b_f < 0` pulls towards the base: compression).
//! The top `X = L0` is traction free and the deformation is uniaxial strain `F = dx/dX`.
//!
//! # Stress (eq. 11)
//!
//! In uniaxial strain the cross-section does not change, so the Cauchy stress equals the nominal
//! stress, and reference equilibrium `d sigma / dX + rho0 b_f = 0` with `sigma(L0) = 0` gives the
//! weight of the material above `X`, independent of the deformation:
//!
//! ```text
//! sigma(X) = rho0 b_f (L0 - X)                                              (11)
//! ```
//!
//! The total weight per unit cross-section, `W = rho0 |b_f| L0`, is the magnitude of the base stress.
//!
//! # Stretch (eqs. 12-14)
//!
//! With `tau = M ln F` (eqs. 12-13; `M` = [`SelfWeightColumn::modulus`], which is `E` for the
//! paper's `nu = 0` and the constrained modulus `lambda + 2 mu` of a Hencky material in general)
//! and `sigma = tau / J`, `J = F`:
//!
//! ```text
//! sigma = M ln(F) / F                                                       (14)
//! ```
//!
//! With `u = ln F` and `s = sigma / M` this is `u exp(-u) = s`. The left side increases
//! monotonically from `-inf` to `1/e` on `u <= 1`, so there is exactly one root with `F <= e`
//! (the branch continuous with `F = 1` at zero stress; `u = -W0(-s)` with Lambert's `W0`) if
//! `s <= 1/e`, and no solution for a tensile stress `sigma > M / e`. It is found by Newton's
//! method safeguarded by bisection on the bracket `[-ln(1 + |s|), 0]` (`s < 0`, because
//! `W0(x) <= ln(1 + x)`) or `[0, 1]` (`s >= 0`), to about 2 ulp in `u`, i.e. ~1e-15 relative
//! in `F`.
//!
//! # Position
//!
//! `x(X) = integral_0^X F dX'` has a closed form. Along the column `ds/dX = -rho0 b_f / M` and
//! `ds = (1 - u) exp(-u) du`, so `F dX = -(M / (rho0 b_f)) (1 - u) du` and
//!
//! ```text
//! x(X) = (M / (rho0 b_f)) (u_0 - u_X) (1 - (u_0 + u_X) / 2),   u_0 = ln F(0), u_X = ln F(X)
//! ```
//!
//! (`x = X` without load). This is exact up to rounding (absolute error a few ulp of `L0`), and
//! for a small load `x(L0) = L0 (1 + s_0/2 + O(s_0^2))` with `s_0 = rho0 b_f L0 / M`, i.e. the
//! linear result `L0 - rho0 |b_f| L0^2 / (2 M)` for `b_f < 0`.
//!
//! # Error measure (eq. 15, generalised)
//!
//! The paper's error `sum_p V0_p |sigma_p - sigma_A(X_p)| / (W L0)` is written for a 1D column of
//! unit cross-section, where `sum_p V0_p = L0`. For any dimension it is normalised by the total
//! reference volume instead,
//!
//! ```text
//! error = sum_p V0_p |sigma_p - sigma_A(X_p)| / (W sum_p V0_p),
//! ```
//!
//! the reference-volume average of the stress error relative to the base stress `W`; it reduces
//! to eq. 15 in 1D and is independent of the column's width and depth in 2D/3D.
//!
//! # Invalid input
//!
//! Nothing panics. The `try_` functions return `Err` for invalid parameters (see
//! [`SelfWeightColumn::validate`]), a non-finite `X`, or a tensile stress above `M / e`;
//! [`SelfWeightColumn::stretch`] and [`SelfWeightColumn::position`] return NaN in those cases.
//! Formulas are evaluated as written for `X` outside `[0, L0]`.

/// Semi-analytic solution of the self-weight column, see the [module docs](self).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SelfWeightColumn {
    /// Reference density `rho0` (> 0).
    pub density: f64,
    /// Body force per unit mass `b_f` along the column axis; negative compresses the column.
    pub body_force: f64,
    /// Reference height `L0` (> 0).
    pub height: f64,
    /// Modulus `M` of `tau = M ln F` (> 0): `E` in the paper, `lambda + 2 mu` for Hencky in general.
    pub modulus: f64,
}

impl SelfWeightColumn {
    /// Checks that `density`, `height` and `modulus` are positive and finite and `body_force`
    /// is finite.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("density", self.density),
            ("height", self.height),
            ("modulus", self.modulus),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(format!(
                    "self-weight column: {name} must be positive and finite, got {value}"
                ));
            }
        }
        if !self.body_force.is_finite() {
            return Err(format!(
                "self-weight column: body force must be finite, got {}",
                self.body_force
            ));
        }
        Ok(())
    }

    /// Total weight per unit cross-section `W = rho0 |b_f| L0` (the magnitude of the base stress).
    pub fn weight(&self) -> f64 {
        self.density * self.body_force.abs() * self.height
    }

    /// Cauchy stress `sigma = rho0 b_f (L0 - X)` (eq. 11); negative (compressive) for `b_f < 0`.
    pub fn stress(&self, reference_x: f64) -> f64 {
        self.density * self.body_force * (self.height - reference_x)
    }

    /// Stretch `F` solving `sigma(X) = M ln F / F` (eq. 14), on the branch `F <= e`; NaN if
    /// [`SelfWeightColumn::try_stretch`] fails.
    pub fn stretch(&self, reference_x: f64) -> f64 {
        self.try_stretch(reference_x).unwrap_or(f64::NAN)
    }

    /// Checked [`SelfWeightColumn::stretch`]: an error for invalid parameters, a non-finite `X`,
    /// or a tensile stress above `M / e` (where eq. 14 has no solution).
    pub fn try_stretch(&self, reference_x: f64) -> Result<f64, String> {
        Ok(self.try_log_stretch(reference_x)?.exp())
    }

    /// Deformed position `x(X) = integral_0^X F dX'` (closed form, see the module docs); NaN if
    /// [`SelfWeightColumn::try_position`] fails.
    pub fn position(&self, reference_x: f64) -> f64 {
        self.try_position(reference_x).unwrap_or(f64::NAN)
    }

    /// Checked [`SelfWeightColumn::position`]: fails where the stretch at `X` or at the base fails.
    pub fn try_position(&self, reference_x: f64) -> Result<f64, String> {
        let log_stretch_here = self.try_log_stretch(reference_x)?;
        let log_stretch_base = self.try_log_stretch(0.0)?;
        let load = self.density * self.body_force;
        if load == 0.0 {
            return Ok(reference_x);
        }
        Ok(self.modulus / load
            * (log_stretch_base - log_stretch_here)
            * (1.0 - 0.5 * (log_stretch_base + log_stretch_here)))
    }

    /// Generalised eq. 15: `sum V0_p |sigma_p - sigma_A(X_p)| / (W sum V0_p)` over points given as
    /// `(reference coordinate along the column X_p, reference volume V0_p, stress along the
    /// column sigma_p)`. NaN when `W sum V0_p` is not positive (no load, or no points).
    pub fn error(&self, points: impl IntoIterator<Item = (f64, f64, f64)>) -> f64 {
        self.error_of_sums(self.error_sums(points))
    }

    /// The two sums of [`Self::error`], `[sum V0_p |sigma_p - sigma_A(X_p)|, sum V0_p]`: a run
    /// whose points are spread over processes adds them over the processes first.
    pub fn error_sums(&self, points: impl IntoIterator<Item = (f64, f64, f64)>) -> [f64; 2] {
        points.into_iter().fold(
            [0.0, 0.0],
            |[weighted_error, volume], (reference_x, reference_volume, stress)| {
                [
                    weighted_error + reference_volume * (stress - self.stress(reference_x)).abs(),
                    volume + reference_volume,
                ]
            },
        )
    }

    /// [`Self::error`] from its two sums ([`Self::error_sums`]).
    pub fn error_of_sums(&self, [weighted_error, volume]: [f64; 2]) -> f64 {
        let normalisation = self.weight() * volume;
        if normalisation > 0.0 {
            weighted_error / normalisation
        } else {
            f64::NAN
        }
    }

    /// `u = ln F(X)`.
    fn try_log_stretch(&self, reference_x: f64) -> Result<f64, String> {
        self.validate()?;
        if !reference_x.is_finite() {
            return Err(format!(
                "self-weight column: reference coordinate must be finite, got {reference_x}"
            ));
        }
        let stress = self.stress(reference_x);
        solve_log_stretch(stress / self.modulus).map_err(|limit| {
            format!(
                "self-weight column: tensile stress {stress:e} at X = {reference_x} exceeds \
                 modulus / e = {:e}, where sigma = M ln F / F has no solution ({limit})",
                self.modulus / std::f64::consts::E
            )
        })
    }
}

/// The root `u <= 1` of `u exp(-u) = s` (`u = ln F`, `s = sigma / M`), or an error if `s > 1/e`.
fn solve_log_stretch(s: f64) -> Result<f64, String> {
    let peak = 1.0 / std::f64::consts::E;
    if s.is_nan() || s > peak {
        return Err(format!("sigma / M = {s} > 1/e"));
    }
    if s == 0.0 {
        return Ok(0.0);
    }
    let residual = |u: f64| u * (-u).exp() - s;
    // Bracket with residual(lower) <= 0 <= residual(upper).
    let (mut lower, mut upper) = if s < 0.0 {
        (-(-s).ln_1p(), 0.0)
    } else {
        (0.0, 1.0)
    };
    for _ in 0..64 {
        if residual(lower) <= 0.0 {
            break;
        }
        lower = 2.0 * lower - 1.0; // only reached through rounding
    }
    let tolerance = 2.0 * f64::EPSILON;
    let mut u = s.clamp(lower, upper); // u = s + O(s^2)
    for _ in 0..200 {
        let decay = (-u).exp();
        let value = u * decay - s;
        if value == 0.0 {
            return Ok(u);
        }
        if value < 0.0 {
            lower = u;
        } else {
            upper = u;
        }
        let newton = u - value / ((1.0 - u) * decay);
        // The slope vanishes only at u = 1; a non-finite step then fails the test and bisects.
        let next = if newton >= lower && newton <= upper {
            newton
        } else {
            0.5 * (lower + upper)
        };
        let converged = (next - u).abs() <= tolerance * next.abs()
            || upper - lower <= 2.0 * tolerance * lower.abs().max(upper.abs());
        u = next;
        if converged {
            break;
        }
    }
    Ok(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's column (rho0 = 1, E = 1e6, L0 = 50) under b_f = -200 (W = 1e4).
    fn paper_column(body_force: f64) -> SelfWeightColumn {
        SelfWeightColumn {
            density: 1.0,
            body_force,
            height: 50.0,
            modulus: 1.0e6,
        }
    }

    fn relative_difference(a: f64, b: f64) -> f64 {
        (a - b).abs() / a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
    }

    /// Composite 5-point Gauss-Legendre quadrature of `stretch` over [0, X]: an independent
    /// route to the position.
    fn integrated_position(column: &SelfWeightColumn, reference_x: f64, panels: usize) -> f64 {
        let a = (245.0 - 14.0 * (70.0_f64).sqrt()).sqrt() / 21.0;
        let b = (245.0 + 14.0 * (70.0_f64).sqrt()).sqrt() / 21.0;
        let wa = (322.0 + 13.0 * (70.0_f64).sqrt()) / 900.0;
        let wb = (322.0 - 13.0 * (70.0_f64).sqrt()) / 900.0;
        let rule = [(0.0, 128.0 / 225.0), (-a, wa), (a, wa), (-b, wb), (b, wb)];
        let h = reference_x / panels as f64;
        (0..panels)
            .map(|panel| {
                let centre = h * (panel as f64 + 0.5);
                rule.iter()
                    .map(|(t, w)| w * column.stretch(centre + 0.5 * h * t))
                    .sum::<f64>()
                    * 0.5
                    * h
            })
            .sum()
    }

    #[test]
    fn weight_and_stress_at_base_and_top() {
        let column = paper_column(-200.0);
        assert_eq!(column.weight(), 1.0e4);
        assert_eq!(column.stress(0.0), -1.0e4);
        assert_eq!(column.stress(50.0), 0.0);
        assert_eq!(column.stress(12.5), -7.5e3);
        assert_eq!(paper_column(-800.0).weight(), 4.0e4);
    }

    #[test]
    fn stretch_reproduces_the_stress() {
        for body_force in [-200.0, -800.0, -1.0e5, -1.0e7, 1.0e3, 7.0e3] {
            let column = paper_column(body_force);
            for i in 0..=20 {
                let reference_x = 50.0 * i as f64 / 20.0;
                let stretch = column.stretch(reference_x);
                let stress = column.modulus * stretch.ln() / stretch;
                let expected = column.stress(reference_x);
                assert!(
                    (stress - expected).abs() <= 1e-14 * column.weight(),
                    "b_f = {body_force}, X = {reference_x}: {stress} vs {expected}"
                );
            }
        }
    }

    #[test]
    fn stretch_matches_the_lambert_series_for_small_stress() {
        // u = -W0(-s) = sum_n n^(n-1) / n! s^n = s + s^2 + 3/2 s^3 + 8/3 s^4 + 125/24 s^5
        //   + 54/5 s^6 + O(s^7)
        for s in [1e-3_f64, -1e-3, 1e-6, -2e-5, 1e-12, -1e-200] {
            let series = s
                + s * s
                + 1.5 * s.powi(3)
                + 8.0 / 3.0 * s.powi(4)
                + 125.0 / 24.0 * s.powi(5)
                + 54.0 / 5.0 * s.powi(6);
            let u = solve_log_stretch(s).unwrap();
            assert!(
                relative_difference(u, series) < 1e-14,
                "{s}: {u} vs {series}"
            );
        }
    }

    #[test]
    fn unit_stretch_at_the_top_and_compression_below() {
        let column = paper_column(-800.0);
        assert_eq!(column.stretch(50.0), 1.0);
        let mut previous = 0.0;
        for i in 0..50 {
            let stretch = column.stretch(i as f64);
            assert!(stretch < 1.0 && stretch > previous);
            previous = stretch;
        }
        // Tension gives F > 1.
        assert!(paper_column(200.0).stretch(0.0) > 1.0);
    }

    #[test]
    fn tension_beyond_modulus_over_e_has_no_solution() {
        // s_0 = rho0 b_f L0 / M: 0.99/e is solvable (F <= e), 1.01/e is not.
        let limit_force = 1.0e6 / std::f64::consts::E / 50.0;
        let solvable = paper_column(0.99 * limit_force);
        let stretch = solvable.try_stretch(0.0).unwrap();
        assert!(stretch > 1.0 && stretch < std::f64::consts::E);
        assert!(relative_difference(1.0e6 * stretch.ln() / stretch, solvable.stress(0.0)) < 1e-13);
        let too_much = paper_column(1.01 * limit_force);
        let message = too_much.try_stretch(0.0).unwrap_err();
        assert!(message.contains("exceeds"), "{message}");
        assert!(too_much.stretch(0.0).is_nan());
        assert!(too_much.position(50.0).is_nan());
        assert!(too_much.try_stretch(45.0).is_ok()); // low enough stress near the top
        // At exactly M/e the root is F = e (to the square-root conditioning of the peak).
        let stretch = solve_log_stretch(1.0 / std::f64::consts::E).unwrap().exp();
        assert!((stretch - std::f64::consts::E).abs() < 1e-6);
    }

    #[test]
    fn position_matches_quadrature_of_the_stretch() {
        for body_force in [-200.0, -800.0, -2.0e4, 5.0e3] {
            let column = paper_column(body_force);
            for reference_x in [50.0, 31.0, 1.0e-3] {
                let closed_form = column.position(reference_x);
                let quadrature = integrated_position(&column, reference_x, 64);
                assert!(
                    (closed_form - quadrature).abs() < 1e-12 * column.height,
                    "b_f = {body_force}, X = {reference_x}: {closed_form} vs {quadrature}"
                );
            }
            assert_eq!(column.position(0.0), 0.0);
        }
    }

    #[test]
    fn position_derivative_is_the_stretch() {
        let column = paper_column(-2.0e4);
        let step = 1e-4;
        for reference_x in [0.5, 10.0, 25.0, 49.5] {
            let derivative = (column.position(reference_x + step)
                - column.position(reference_x - step))
                / (2.0 * step);
            assert!(relative_difference(derivative, column.stretch(reference_x)) < 1e-8);
        }
    }

    #[test]
    fn small_load_limit_is_linear_elastic() {
        for body_force in [-2.0, -0.2, -0.02, -2.0e-5] {
            let column = paper_column(body_force);
            let linear = column.height
                - column.density * body_force.abs() * column.height.powi(2)
                    / (2.0 * column.modulus);
            let s0 = column.stress(0.0) / column.modulus;
            let difference = column.position(column.height) - linear;
            // x(L0) = L0 (1 + s0/2 + s0^2/2 + O(s0^3)), so the difference is ~ L0 s0^2 / 2.
            assert!(
                (difference - 0.5 * column.height * s0 * s0).abs()
                    <= column.height * (s0.abs().powi(3) + 1e-15),
                "b_f = {body_force}: difference {difference:e}"
            );
        }
        let unloaded = paper_column(0.0);
        assert_eq!(unloaded.position(17.0), 17.0);
        assert_eq!(unloaded.stretch(3.0), 1.0);
    }

    #[test]
    fn error_measure() {
        let column = paper_column(-200.0); // W = 1e4
        let exact: Vec<_> = (0..50)
            .map(|i| {
                let x = i as f64 + 0.5;
                (x, 1.0, column.stress(x))
            })
            .collect();
        assert_eq!(column.error(exact.iter().copied()), 0.0);
        // 1D, V0 = 1 per point, sum V0 = L0 = 50: perturbing one point by 100 and another by -300
        // gives (100 + 300) / (1e4 * 50) = 8e-4.
        let mut perturbed = exact.clone();
        perturbed[3].2 += 100.0;
        perturbed[40].2 -= 300.0;
        assert!((column.error(perturbed.iter().copied()) - 8e-4).abs() < 1e-18);
        // Width 2 (2D): volumes double, the measure is unchanged.
        let widened = perturbed.iter().map(|&(x, v, s)| (x, 2.0 * v, s));
        assert!((column.error(widened) - 8e-4).abs() < 1e-18);
        // Unequal volumes: (0.5 * 10 + 1.5 * 20) / (1e4 * 2) = 1.75e-3.
        let points = [
            (10.0, 0.5, column.stress(10.0) + 10.0),
            (20.0, 1.5, column.stress(20.0) - 20.0),
        ];
        assert!((column.error(points) - 1.75e-3).abs() < 1e-18);
        // Undefined normalisation.
        assert!(column.error(std::iter::empty()).is_nan());
        assert!(paper_column(0.0).error(exact).is_nan());
    }

    #[test]
    fn invalid_parameters_are_errors_not_panics() {
        let good = paper_column(-200.0);
        let bad = [
            SelfWeightColumn {
                modulus: 0.0,
                ..good
            },
            SelfWeightColumn {
                modulus: f64::NAN,
                ..good
            },
            SelfWeightColumn {
                density: -1.0,
                ..good
            },
            SelfWeightColumn {
                height: f64::INFINITY,
                ..good
            },
            SelfWeightColumn {
                body_force: f64::NAN,
                ..good
            },
        ];
        for column in bad {
            assert!(column.validate().is_err());
            assert!(column.try_stretch(1.0).is_err());
            assert!(column.try_position(1.0).is_err());
            assert!(column.stretch(1.0).is_nan());
            assert!(column.position(1.0).is_nan());
        }
        assert!(good.try_stretch(f64::NAN).is_err());
        assert!(good.position(f64::INFINITY).is_nan());
    }
}
