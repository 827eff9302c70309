//! The compressible elasto-plastic thick-walled cylinder: a 1D radial finite-element reference,
//! independent of the MPM (docs/plasticity.md, "Benchmark 3").
//!
//! # Problem
//!
//! A plane-strain tube `a ≤ r ≤ b` of an isotropic, compressible elastic (E, ν), perfectly
//! plastic von Mises material (σ_y), small strain, loaded by an internal pressure `p` (outer
//! surface free). The fields are axisymmetric: a radial displacement `u(r)`, strains
//!
//! ```text
//! ε_r = du/dr,   ε_θ = u/r,   ε_z = 0
//! ```
//!
//! and principal stresses (σ_r, σ_θ, σ_z). Equilibrium in weak form, per radian and unit length
//! along the axis, for every virtual `δu` with `δu(a)` free:
//!
//! ```text
//! ∫_a^b (σ_r δε_r + σ_θ δε_θ) r dr = p a δu(a)
//! ```
//!
//! Hill's closed form needs incompressibility (σ_z the in-plane mean in the plastic zone); with
//! ν < 1/2 σ_z depends on the loading path and the curve is integrated numerically here.
//!
//! # Discretisation
//!
//! Quadratic elements in r (three nodes, equal lengths h = (b − a)/n) with the two-point Gauss
//! rule: the u/r term is not polynomial, the rule is exact for cubics, and two points per
//! element against 2n + 1 unknowns leave the incompressible field u = C/r representable, so the
//! element does not lock as ν → 1/2 (three points would). The pressure is the reaction of the
//! prescribed u(a): `p = f_int,0 / a` (the internal force at the inner node; the other nodes
//! are in equilibrium). Driving u(a) rather than p passes the limit pressure without trouble.
//!
//! # Stress update (radial return)
//!
//! With the committed plastic strain ε^p (deviatoric, principal components), the trial stress
//! is σ* = K tr(ε − ε^p) 1 + 2G dev(ε − ε^p); if q* = √(3/2) |s*| ≤ σ_y it is the stress,
//! otherwise β = σ_y / q*, s = β s*, ε^p += (1 − β) s*/(2G), and the consistent tangent
//! (de Souza Neto et al., perfect plasticity) is
//!
//! ```text
//! D = K 1⊗1 + 2G β (I_dev − n⊗n),   n = s*/|s*|
//! ```
//!
//! of which the (r, θ) block enters the element stiffness (ε_z stays 0). Shear stresses are
//! zero by symmetry, so the update on the three principal components is the full one.
//!
//! # Loading
//!
//! u(a) is moved to each requested value in equal sub-increments no larger than
//! `u_e / 40` (u_e: the Lamé expansion at the elastic limit p_e), with Newton per increment to a
//! residual below 1e-10 of the reaction (round-off in the nodal sums is about 1e-12 of it) or a
//! correction below 1e-13 of the displacement (round-off at ν → 1/2, where the bulk terms are
//! large). The half-bandwidth of the stiffness is 2: it is solved
//! by banded Gaussian elimination (no pivoting; K is positive definite, the bulk modulus keeps
//! it so when the whole wall yields).
//!
//! # Closed forms
//!
//! Lamé (plane strain): σ_r = C − D/r², σ_θ = C + D/r², σ_z = 2νC with C = p a²/(b² − a²),
//! D = p a² b²/(b² − a²) and u(r) = (1 + ν)/E ((1 − 2ν) C r + D/r). The first yield is at
//! r = a (every stress difference grows as 1/r² towards the bore): p_e = σ_y / q(p = 1, r = a).
//! The limit pressure, σ_θ − σ_r = 2σ_y/√3 through the wall once σ_z has become the in-plane
//! mean: p_lim = (2/√3) σ_y ln(b/a), approached as the plastic flow grows.
//!
//! # Past the limit: the fully plastic wall at finite strain
//!
//! The model above is small-strain: its pressure tends to p_lim and stays there. A wall that
//! expands thins, and the pressure it carries falls ([`ThickCylinder::fully_plastic_pressure`]).
//! Once the whole wall yields, take the elastic strains as negligible (rigid-perfectly
//! plastic, von Mises, plane strain) and write equilibrium in the *current* configuration,
//! with the current radii a ≤ r ≤ b and the Cauchy stresses:
//!
//! ```text
//! dσ_r/dr + (σ_r − σ_θ)/r = 0,   σ_r(a) = −p,   σ_r(b) = 0.
//! ```
//!
//! Plastic flow is isochoric and ε̇_z = 0, so the associated flow rule makes the deviatoric
//! s_z = 0: σ_z = (σ_r + σ_θ)/2, and von Mises' q = (√3/2) |σ_θ − σ_r| = σ_y gives
//! σ_θ − σ_r = (2/√3) σ_y at every radius. Integrating from a to b:
//!
//! ```text
//! p = (2/√3) σ_y ln(b/a).
//! ```
//!
//! This is p_lim's formula, but with the current radii. The material is incompressible, so
//! the area of the annulus is kept, b² − a² = b₀² − a₀², and with a = a₀ + u(a)
//!
//! ```text
//! p(u) = (1/√3) σ_y ln((b₀² − a₀² + a²) / a²),
//! dp/du at u = 0: (2/√3) σ_y (a₀/b₀² − 1/a₀)
//! ```
//!
//! (for a₀ = 1, b₀ = 2: p/p_lim − 1 = −1.07 % at u(a) = 0.01 a₀, −5.2 % at 0.05 a₀,
//! −10.1 % at 0.1 a₀; the slope is −0.75/ln 2 = −1.08 p_lim per a₀).
//!
//! What it neglects. (1) The elastic strains, of order σ_y/E: the wall must have yielded
//! through (u(a) ≳ 0.007 a for E = 500 σ_y, b = 2a), and with ν < 1/2 σ_z reaches the
//! in-plane mean only as the plastic flow grows (the small-strain model above has the pressure
//! still 1.55e-3 below p_lim at u(a) = 0.01 a, 6.4e-5 at 0.02 a, at ν = 0.3). (2) The elastic
//! change of volume, a relative change of the annulus' area of order (1 − 2ν) σ_y/E (8e-4 at
//! ν = 0.3, E = 500 σ_y; 4e-5 at ν = 0.49), which moves b and the pressure by less than 1e-3
//! relative. Both are below the MPM's errors here; the formula is an asymptote, not the curve
//! before the wall has yielded through.

/// The tube and its material (plane strain, small strain, von Mises, perfect plasticity).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThickCylinder {
    /// Inner radius a.
    pub inner: f64,
    /// Outer radius b.
    pub outer: f64,
    /// Young's modulus E.
    pub youngs_modulus: f64,
    /// Poisson's ratio ν (compressible: below 1/2).
    pub poisson_ratio: f64,
    /// Yield stress σ_y (von Mises).
    pub yield_stress: f64,
}

/// The state of the tube at one prescribed inner displacement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CylinderResponse {
    /// u(a), as prescribed.
    pub inner_displacement: f64,
    /// The pressure on the bore that holds it there (the reaction per unit inner length).
    pub pressure: f64,
    /// The largest radius of a Gauss point that has yielded (a when none has).
    pub plastic_radius: f64,
}

/// Gauss points of the two-point rule on [−1, 1].
const GAUSS: [f64; 2] = [-0.577_350_269_189_625_8, 0.577_350_269_189_625_8];

impl ThickCylinder {
    fn shear_modulus(&self) -> f64 {
        self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))
    }

    fn bulk_modulus(&self) -> f64 {
        self.youngs_modulus / (3.0 * (1.0 - 2.0 * self.poisson_ratio))
    }

    /// The pressure that expands the bore elastically by u(a) (plane-strain Lamé).
    pub fn lame_pressure(&self, inner_displacement: f64) -> f64 {
        let (a, b, nu) = (self.inner, self.outer, self.poisson_ratio);
        inner_displacement * self.youngs_modulus * (b * b - a * a)
            / ((1.0 + nu) * a * ((1.0 - 2.0 * nu) * a * a + b * b))
    }

    /// The first yield pressure of the compressible Lamé field (at r = a, σ_z = ν(σ_r + σ_θ)).
    pub fn elastic_limit_pressure(&self) -> f64 {
        let (a, b, nu) = (self.inner, self.outer, self.poisson_ratio);
        let c = a * a / (b * b - a * a);
        let d = a * a * b * b / (b * b - a * a) / (a * a);
        let stress = [c - d, c + d, 2.0 * nu * c];
        self.yield_stress / von_mises(&stress)
    }

    /// The limit pressure (2/√3) σ_y ln(b/a).
    pub fn limit_pressure(&self) -> f64 {
        2.0 / 3f64.sqrt() * self.yield_stress * (self.outer / self.inner).ln()
    }

    /// The pressure on the bore of the fully plastic, incompressible wall at finite strain
    /// after the bore has moved out by `inner_displacement` (module docs, "Past the limit"):
    /// (2/√3) σ_y ln(b/a) with the current radii a = a₀ + u(a), b = √(b₀² − a₀² + a²). It
    /// equals [`ThickCylinder::limit_pressure`] at u(a) = 0 and falls as the wall thins. Valid
    /// once the whole wall has yielded; it ignores E and ν (elastic strains of order σ_y/E).
    pub fn fully_plastic_pressure(&self, inner_displacement: f64) -> f64 {
        let (a0, b0) = (self.inner, self.outer);
        let a = a0 + inner_displacement;
        let b_squared = b0 * b0 - a0 * a0 + a * a;
        self.yield_stress / 3f64.sqrt() * (b_squared / (a * a)).ln()
    }

    /// The tube's response at each of `expansions` (values of u(a), reached in this order from
    /// the unloaded state) with `elements` quadratic elements across the wall. An error names
    /// the increment whose Newton iterations did not converge.
    pub fn bore_pressures(
        &self,
        elements: usize,
        expansions: &[f64],
    ) -> Result<Vec<CylinderResponse>, String> {
        if elements == 0 || !(self.inner > 0.0 && self.outer > self.inner) {
            return Err(format!(
                "thick cylinder: need 0 < a < b and at least one element (a = {}, b = {}, {elements} elements)",
                self.inner, self.outer
            ));
        }
        if !(self.poisson_ratio < 0.5 && self.poisson_ratio > -1.0) {
            return Err(format!(
                "thick cylinder: the reference is compressible: ν = {} must be in (−1, 1/2)",
                self.poisson_ratio
            ));
        }
        let mut model = RadialModel::new(self, elements);
        let largest_increment = 0.025 * self.elastic_limit_pressure() / self.lame_pressure(1.0);
        let mut responses = Vec::with_capacity(expansions.len());
        let mut current = 0.0;
        for &target in expansions {
            let parts = ((target - current).abs() / largest_increment)
                .ceil()
                .max(1.0) as usize;
            let start = current;
            for k in 1..=parts {
                let u_a = start + (target - start) * k as f64 / parts as f64;
                model.solve_increment(u_a).map_err(|iterations| {
                    format!("thick cylinder: Newton did not converge at u(a) = {u_a:e} in {iterations} iterations")
                })?;
            }
            current = target;
            responses.push(CylinderResponse {
                inner_displacement: target,
                pressure: model.reaction() / self.inner,
                plastic_radius: model.plastic_radius(),
            });
        }
        Ok(responses)
    }
}

/// √(3/2) |dev σ| of principal stresses.
fn von_mises(stress: &[f64; 3]) -> f64 {
    let [x, y, z] = *stress;
    (0.5 * ((x - y).powi(2) + (y - z).powi(2) + (z - x).powi(2))).sqrt()
}

/// The radial-return update at one Gauss point: the stress, the (r, θ) block of the
/// consistent tangent, and the plastic strain after the step.
pub fn radial_return(
    tube: &ThickCylinder,
    strain: [f64; 2],
    plastic: [f64; 3],
) -> ([f64; 3], [[f64; 2]; 2], [f64; 3]) {
    let (shear, bulk) = (tube.shear_modulus(), tube.bulk_modulus());
    let elastic = [strain[0] - plastic[0], strain[1] - plastic[1], -plastic[2]];
    let volume = elastic.iter().sum::<f64>();
    let deviator: [f64; 3] = std::array::from_fn(|i| 2.0 * shear * (elastic[i] - volume / 3.0));
    let norm = deviator.iter().map(|s| s * s).sum::<f64>().sqrt();
    let q = 1.5f64.sqrt() * norm;
    let beta = if q > tube.yield_stress {
        tube.yield_stress / q
    } else {
        1.0
    };
    let stress = std::array::from_fn(|i| bulk * volume + beta * deviator[i]);
    let new_plastic =
        std::array::from_fn(|i| plastic[i] + (1.0 - beta) * deviator[i] / (2.0 * shear));
    let tangent = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let identity = if i == j { 1.0 } else { 0.0 };
            let mut d = bulk + 2.0 * shear * beta * (identity - 1.0 / 3.0);
            if beta < 1.0 {
                d -= 2.0 * shear * beta * deviator[i] * deviator[j] / (norm * norm);
            }
            d
        })
    });
    (stress, tangent, new_plastic)
}

/// The discretised tube: nodes, the displacement and each Gauss point's committed plastic
/// strain.
struct RadialModel<'a> {
    tube: &'a ThickCylinder,
    elements: usize,
    length: f64,
    displacement: Vec<f64>,
    committed: Vec<[f64; 3]>,
    trial: Vec<[f64; 3]>,
}

impl<'a> RadialModel<'a> {
    fn new(tube: &'a ThickCylinder, elements: usize) -> Self {
        Self {
            tube,
            elements,
            length: (tube.outer - tube.inner) / elements as f64,
            displacement: vec![0.0; 2 * elements + 1],
            committed: vec![[0.0; 3]; 2 * elements],
            trial: vec![[0.0; 3]; 2 * elements],
        }
    }

    fn node_radius(&self, node: usize) -> f64 {
        self.tube.inner + 0.5 * self.length * node as f64
    }

    /// The internal force and (banded, half-bandwidth 2: `stiffness[i][2 + j − i]`) stiffness
    /// at the current displacement; the trial plastic strains are kept.
    fn assemble(&mut self) -> (Vec<f64>, Vec<[f64; 5]>) {
        let dofs = self.displacement.len();
        let mut force = vec![0.0; dofs];
        let mut stiffness = vec![[0.0; 5]; dofs];
        for e in 0..self.elements {
            let nodes = [2 * e, 2 * e + 1, 2 * e + 2];
            for (g, &xi) in GAUSS.iter().enumerate() {
                let shape = [0.5 * xi * (xi - 1.0), 1.0 - xi * xi, 0.5 * xi * (xi + 1.0)];
                let slope = [xi - 0.5, -2.0 * xi, xi + 0.5].map(|d| d * 2.0 / self.length);
                let r: f64 = (0..3).map(|k| shape[k] * self.node_radius(nodes[k])).sum();
                let strain = [
                    (0..3).map(|k| slope[k] * self.displacement[nodes[k]]).sum(),
                    (0..3)
                        .map(|k| shape[k] * self.displacement[nodes[k]])
                        .sum::<f64>()
                        / r,
                ];
                let point = 2 * e + g;
                let (stress, tangent, plastic) =
                    radial_return(self.tube, strain, self.committed[point]);
                self.trial[point] = plastic;
                let weight = r * 0.5 * self.length;
                let rows: [[f64; 2]; 3] = std::array::from_fn(|k| [slope[k], shape[k] / r]);
                for k in 0..3 {
                    force[nodes[k]] += weight * (rows[k][0] * stress[0] + rows[k][1] * stress[1]);
                    for l in 0..3 {
                        let mut entry = 0.0;
                        for i in 0..2 {
                            for j in 0..2 {
                                entry += rows[k][i] * tangent[i][j] * rows[l][j];
                            }
                        }
                        stiffness[nodes[k]][2 + nodes[l] - nodes[k]] += weight * entry;
                    }
                }
            }
        }
        (force, stiffness)
    }

    /// Newton for the free nodes with u(a) = `inner`; commits the plastic strains. Err: the
    /// iterations spent.
    fn solve_increment(&mut self, inner: f64) -> Result<(), usize> {
        self.displacement[0] = inner;
        let mut last_correction = f64::INFINITY;
        for iteration in 0..50 {
            let (force, stiffness) = self.assemble();
            let scale = force[0].abs().max(1e-300);
            let residual = force[1..].iter().fold(0.0f64, |m, f| m.max(f.abs()));
            if residual <= 1e-10 * scale || last_correction <= 1e-13 {
                self.committed.clone_from(&self.trial);
                return Ok(());
            }
            if iteration == 49 || !residual.is_finite() {
                break;
            }
            let correction = solve_banded(&stiffness[1..], &force[1..]);
            let size = self.displacement.iter().fold(0.0f64, |m, u| m.max(u.abs()));
            last_correction = correction.iter().fold(0.0f64, |m, d| m.max(d.abs())) / size;
            for (u, du) in self.displacement[1..].iter_mut().zip(correction) {
                *u -= du;
            }
        }
        Err(50)
    }

    fn reaction(&mut self) -> f64 {
        self.assemble().0[0]
    }

    fn plastic_radius(&self) -> f64 {
        let mut radius = self.tube.inner;
        for (point, plastic) in self.committed.iter().enumerate() {
            if plastic.iter().any(|p| *p != 0.0) {
                let (e, g) = (point / 2, point % 2);
                let centre = self.node_radius(2 * e + 1);
                radius = radius.max(centre + 0.5 * self.length * GAUSS[g]);
            }
        }
        radius
    }
}

/// Solves K x = f for a banded K (`rows[i][2 + j − i]` = K_ij, |i − j| ≤ 2; the rows of the
/// free nodes, column offsets relative to them) by Gaussian elimination without pivoting.
fn solve_banded(rows: &[[f64; 5]], rhs: &[f64]) -> Vec<f64> {
    let n = rows.len();
    let mut k = rows.to_vec();
    let mut f = rhs.to_vec();
    for p in 0..n {
        for i in p + 1..(p + 3).min(n) {
            let factor = k[i][2 + p - i] / k[p][2];
            for j in p..(p + 3).min(n) {
                k[i][2 + j - i] -= factor * k[p][2 + j - p];
            }
            f[i] -= factor * f[p];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let mut sum = f[i];
        for j in i + 1..(i + 3).min(n) {
            sum -= k[i][2 + j - i] * x[j];
        }
        x[i] = sum / k[i][2];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tube(poisson_ratio: f64) -> ThickCylinder {
        ThickCylinder {
            inner: 1.0,
            outer: 2.0,
            youngs_modulus: 500.0,
            poisson_ratio,
            yield_stress: 1.0,
        }
    }

    /// The elastic range: the reaction against Lamé's plane-strain pressure to 1e-8 (200
    /// elements; measured 1.6e-13), and no point yielded. The elastic reaction of these
    /// elements is Lamé's to round-off at any element count (measured 4e-16 with one element,
    /// 5e-15 with 16): this checks the formulation, not the resolution, which the plastic
    /// range's convergence test does.
    #[test]
    fn the_elastic_range_is_lames() {
        let tube = tube(0.3);
        let u_e = tube.elastic_limit_pressure() / tube.lame_pressure(1.0);
        let expansions = [0.25 * u_e, 0.5 * u_e, 0.99 * u_e];
        let responses = tube.bore_pressures(200, &expansions).unwrap();
        for response in responses {
            let exact = tube.lame_pressure(response.inner_displacement);
            let error = response.pressure / exact - 1.0;
            println!(
                "u(a) = {:.4e}: p = {:.10}, Lamé {exact:.10}, {error:+.2e}",
                response.inner_displacement, response.pressure
            );
            assert!(error.abs() < 1e-8, "{error:e}");
            assert_eq!(response.plastic_radius, 1.0);
        }
    }

    /// The first yield pressure 0.4323 σ_y at ν = 0.3 (b/a = 2), and the tube yields just past
    /// the Lamé expansion of p_e.
    #[test]
    fn the_first_yield_is_the_compressible_closed_form() {
        let tube = tube(0.3);
        let p_e = tube.elastic_limit_pressure();
        println!("p_e = {p_e:.6}");
        assert!((p_e - 0.4323).abs() < 5e-5, "{p_e}");
        let u_e = p_e / tube.lame_pressure(1.0);
        let below = tube.bore_pressures(400, &[0.999 * u_e]).unwrap()[0];
        let above = tube.bore_pressures(400, &[1.002 * u_e]).unwrap()[0];
        assert_eq!(below.plastic_radius, 1.0);
        assert!(above.plastic_radius > 1.0, "{above:?}");
    }

    /// The consistent tangent against central differences of the stress.
    #[test]
    fn the_return_tangent_matches_finite_differences() {
        let tube = tube(0.3);
        for (strain, plastic) in [
            ([1e-3, -2e-3], [0.0; 3]),
            ([4e-3, -1e-3], [1e-3, -5e-4, -5e-4]),
            ([-3e-3, 5e-3], [-1e-3, 2e-3, -1e-3]),
        ] {
            let (_, tangent, _) = radial_return(&tube, strain, plastic);
            for j in 0..2 {
                let step = 1e-7;
                let mut plus = strain;
                let mut minus = strain;
                plus[j] += step;
                minus[j] -= step;
                let (sp, ..) = radial_return(&tube, plus, plastic);
                let (sm, ..) = radial_return(&tube, minus, plastic);
                for i in 0..2 {
                    let difference = (sp[i] - sm[i]) / (2.0 * step);
                    assert!(
                        (difference - tangent[i][j]).abs() < 1e-6 * tube.youngs_modulus,
                        "{strain:?}: D[{i}][{j}] = {} against {difference}",
                        tangent[i][j]
                    );
                }
            }
        }
    }

    /// The curve converges with the number of radial elements: at 100 and 200 elements the
    /// pressures differ by less than 1e-5 σ_y from the elastic range to u(a) = 0.01 a
    /// (measured 3.0e-6 σ_y, where the plastic front crosses a Gauss point; the plastic radii
    /// agree within one element, 0.01 a).
    #[test]
    fn the_curve_converges_with_the_radial_elements() {
        let tube = tube(0.3);
        let expansions: Vec<f64> = (1..=40).map(|k| 0.00025 * k as f64).collect();
        let coarse = tube.bore_pressures(100, &expansions).unwrap();
        let fine = tube.bore_pressures(200, &expansions).unwrap();
        let mut largest = 0.0f64;
        for (c, f) in coarse.iter().zip(&fine) {
            println!(
                "u(a) = {:.5}: p = {:.8} / {:.8}, plastic radius {:.4} / {:.4}",
                c.inner_displacement, c.pressure, f.pressure, c.plastic_radius, f.plastic_radius
            );
            largest = largest.max((c.pressure - f.pressure).abs());
            assert!(
                (c.plastic_radius - f.plastic_radius).abs() <= 0.01,
                "{c:?} {f:?}"
            );
        }
        println!("largest difference {largest:e}");
        assert!(largest < 1e-5, "{largest:e}");
    }

    /// The finite-strain fully plastic pressure (a₀ = 1, b₀ = 2): p_lim at u(a) = 0 (to
    /// round-off), and below it by the figures worked by hand from b² = 3 + a²: −1.0740 % at
    /// u(a) = 0.01 a₀ (a = 1.01, b = 2.00502), −5.2138 % at 0.05 a₀ (1.05, 2.02546),
    /// −10.0593 % at 0.1 a₀ (1.1, 2.05183), each to 1e-6; the slope at u = 0 against
    /// (2/√3) σ_y (a₀/b₀² − 1/a₀) by central differences (1e-6 relative); the pressure
    /// falls monotonically, proportional to σ_y and independent of E and ν.
    #[test]
    fn the_fully_plastic_pressure_falls_as_the_wall_thins() {
        let tube = tube(0.3);
        let limit = tube.limit_pressure();
        assert!((tube.fully_plastic_pressure(0.0) / limit - 1.0).abs() < 1e-14);
        for (u, expected) in [(0.01, -0.010740), (0.05, -0.052138), (0.1, -0.100593)] {
            let fall = tube.fully_plastic_pressure(u) / limit - 1.0;
            println!("u(a) = {u}: p/p_lim − 1 = {fall:+.7}");
            assert!((fall - expected).abs() < 1e-6, "u(a) = {u}: {fall}");
        }
        let step = 1e-6;
        let slope =
            (tube.fully_plastic_pressure(step) - tube.fully_plastic_pressure(-step)) / (2.0 * step);
        let exact = 2.0 / 3f64.sqrt() * (1.0 / 4.0 - 1.0);
        assert!(
            (slope / exact - 1.0).abs() < 1e-6,
            "{slope} against {exact}"
        );
        let curve: Vec<f64> = (0..=100)
            .map(|k| tube.fully_plastic_pressure(0.002 * k as f64))
            .collect();
        assert!(curve.windows(2).all(|w| w[1] < w[0]));
        let other = ThickCylinder {
            youngs_modulus: 1e4,
            poisson_ratio: 0.49,
            yield_stress: 2.5,
            ..tube
        };
        let ratio = other.fully_plastic_pressure(0.05) / tube.fully_plastic_pressure(0.05);
        assert!((ratio - 2.5).abs() < 1e-13, "{ratio}");
    }

    /// The limit pressure: past the full yield of the wall (u(a) ≈ 0.0075 a) the pressure
    /// rises towards (2/√3) σ_y ln(b/a) from below as σ_z becomes the in-plane mean. Measured
    /// (100 elements): −1.55e-3 at u(a) = 0.01 a, −6.4e-5 at 0.02 a, −6.0e-9 at 0.05 a,
    /// −2.3e-11 at 0.2 a.
    #[test]
    fn the_pressure_tends_to_the_limit_pressure() {
        let tube = tube(0.3);
        let limit = tube.limit_pressure();
        let responses = tube.bore_pressures(100, &[0.01, 0.02, 0.05, 0.2]).unwrap();
        for r in &responses {
            println!(
                "u(a) = {}: p = {:.8} ({:+.3e} from p_lim), plastic radius {:.4}",
                r.inner_displacement,
                r.pressure,
                r.pressure / limit - 1.0,
                r.plastic_radius
            );
            assert!(r.pressure < limit * (1.0 + 1e-12), "{r:?}");
            assert!(r.plastic_radius > 1.99, "{r:?}");
        }
        for pair in responses.windows(2) {
            assert!(pair[1].pressure > pair[0].pressure, "{pair:?}");
        }
        assert!(
            (responses[2].pressure / limit - 1.0).abs() < 1e-7,
            "{:?}",
            responses[2]
        );
        assert!(
            (responses[3].pressure / limit - 1.0).abs() < 1e-9,
            "{:?}",
            responses[3]
        );
    }
}
