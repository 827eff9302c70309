//! Mohr–Coulomb plasticity at finite strain (perfect, or with linear hardening or softening of
//! the cohesion), with an optional tension cut-off.
//!
//! Tension positive. In principal Kirchhoff stresses the yield surface is the intersection of the
//! six planes (one for each ordered pair `i ≠ j` of principal directions)
//!
//! ```text
//! Φ_ij = (τ_i − τ_j) + (τ_i + τ_j) sin φ − 2 c cos φ ≤ 0
//! ```
//!
//! and, with a tension cut-off `t`, the three Rankine planes `τ_i − t ≤ 0`. For the ordered
//! stresses `τ_1 ≥ τ_2 ≥ τ_3` the active plane is `Φ_13`; its neighbours `Φ_12` and `Φ_23`
//! meet it on the edges (triaxial extension and compression), and the three meet at the apex
//! `τ = c cot φ 1`. The plastic potential has the same planes with the dilation angle ψ
//! (`Ψ_ij = (τ_i − τ_j) + (τ_i + τ_j) sin ψ`); the Rankine planes are associated.
//!
//! # Return map (multi-surface, in principal logarithmic strain space)
//!
//! Every plane is linear and there is no hardening, so the return to a set `S` of active planes
//! (rows `a_i` of the yield planes, `b_i` of the potential planes, `τ^tr = D_e ε^tr`) is the
//! solution of one small linear system (de Souza Neto et al., sec. 8.2, boxes 8.4–8.5, which
//! treat the plane, the two edges and the apex each by hand; this is the same in one form):
//!
//! ```text
//! M Δγ = Φ_S(τ^tr),   M_ij = a_i · D_e b_j,   τ = τ^tr − D_e B Δγ,
//! D = ∂τ/∂ε^tr = D_e − D_e B M⁻¹ Aᵀ D_e
//! ```
//!
//! The return tries the sets of one, two and three planes in turn and takes the first that is
//! consistent: `Δγ ≥ 0` and no plane violated at `τ`. One plane is the return to the plane, two
//! are an edge (or a plane meeting the cut-off), three are the apex (`D = 0`). For associated
//! flow these are the Kuhn–Tucker conditions of the closest-point projection in the energy norm,
//! which has one solution; for non-associated flow the apex is accepted when no set passes
//! (where its multipliers may have either sign), as the point `c cot φ 1` itself. `D` is non-symmetric unless `ψ = φ`.
//!
//! `φ = 0` with `ψ = 0` is Tresca's criterion (`c` the shear strength), without an apex.
//!
//! # Hardening and softening of the cohesion
//!
//! `c(ε̄_p) = max(c + H ε̄_p, c_r)` (`H`, `c_residual`: `cohesion.rs`) with the equivalent plastic
//! strain `Δε̄_p = k Σ_i Δγ_i` over the active Mohr–Coulomb planes (the cut-off's flow does not
//! enter; its `t` stays), `k = √(((1 + sin ψ)² + 2 (1 − sin ψ)²)/3)`: in triaxial compression
//! (the compressive edge, `Δγ_12 = Δγ_13`) `Δε_p = ½ Σ Δγ (1 + sin ψ, 1 + sin ψ, −2 (1 − sin ψ))`
//! and `k Σ Δγ = √(2/3) ‖Δε_p‖`, the usual measure (on the plane and the other edge it is a
//! definition; de Souza Neto et al. take `2 cos φ Σ Δγ`, the same law with `H` scaled). Every
//! Mohr–Coulomb plane's level `2 c cos φ` then rises by `2 cos φ k h` per unit of every
//! Mohr–Coulomb multiplier (`h` the branch's slope, 0 at the residual), so the return to a set
//! is still one linear system, the hardening entering `M`:
//!
//! ```text
//! M_ij = a_i · D_e b_j + 2 cos φ k h [i, j Mohr–Coulomb planes],   M Δγ = Φ_S(τ^tr; c_n),
//! τ = τ^tr − D_e B Δγ,   D = D_e − D_e B M⁻¹ Aᵀ D_e
//! ```
//!
//! and admissibility is checked against the raised levels. Every Mohr–Coulomb flow has
//! `tr b = 2 sin ψ`, so for `ψ > 0` `Δε̄_p = k Δε_v^p / (2 sin ψ)` whatever the set: the apex
//! taken where no set passes (non-associated flow) is `p = cot φ c(ε̄_p^n + k (p^tr − p)/(2K sin ψ))`,
//! with `g = cot φ h k/(2K sin ψ)`: `p = (cot φ c_n + g p^tr)/(1 + g)`, `D = g K/(1 + g) 1⊗1`,
//! continuous with the sets' apex. For `ψ = 0` there is no volumetric flow: with `h > 0` the
//! three-plane set hardens the apex to `p^tr` (found by the sets); with `h ≤ 0` the apex
//! `cot φ c(ε̄_p^n + Δε̄_p)` with `Δε̄_p = √(2/3) ‖dev ε^tr‖` (the deviator removed),
//! `D = cot φ h √(2/3) 1⊗N` (here `ε̄_p` jumps where the sets stop passing). The cut-off corner
//! keeps `D = 0`, `Δε̄_p = 0`.
//!
//! The return is unique while `1 + 2 cos φ k H 1ᵀ M₀⁻¹ 1 > 0` for the plane, both edges and the
//! apex (`M₀` without hardening) and `1 + g > 0`: a steeper softening is refused
//! ([`MohrCoulomb::softening_limit`]), as is a cut-off above the softened apex `c_r cot φ`.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::cohesion::CohesionHardening;
use super::drucker_prager::{
    SOFTENING_OPTIONS, check_strength, read_strength, strength_parameters,
};
use super::elastoplastic::{
    self, PlasticHistory, PrincipalReturn, bulk_and_shear, deviator, elasticity,
};
use super::{Hencky, Material, MaterialParameters, ParameterKind, ParameterSpec, Range, Response};

/// Mohr–Coulomb perfect plasticity (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct MohrCoulomb {
    pub elastic: Hencky,
    /// Cohesion `c`.
    pub cohesion: f64,
    /// Friction angle φ in radians.
    pub friction: f64,
    /// Dilation angle ψ in radians.
    pub dilation: f64,
    /// Tensile strength of the cut-off, if any.
    pub tension_cutoff: Option<f64>,
    /// The hardening or softening of the cohesion (default: none, perfect plasticity).
    pub hardening: CohesionHardening,
}

/// One plane of the surface: yield normal `a`, flow direction `b`, `a · τ ≤ level`; the
/// Mohr–Coulomb planes' level follows the cohesion (`hardens`), the cut-off's does not.
#[derive(Clone, Copy, Debug)]
struct Plane {
    normal: Vector3<f64>,
    flow: Vector3<f64>,
    level: f64,
    hardens: bool,
}

impl MohrCoulomb {
    /// A Mohr–Coulomb material (angles in degrees), or why the parameters make none.
    pub fn new(
        elastic: Hencky,
        cohesion: f64,
        friction_degrees: f64,
        dilation_degrees: f64,
        tension_cutoff: Option<f64>,
    ) -> Result<Self, String> {
        check_strength(cohesion, friction_degrees, dilation_degrees)?;
        let model = Self {
            elastic,
            cohesion,
            friction: friction_degrees.to_radians(),
            dilation: dilation_degrees.to_radians(),
            tension_cutoff,
            hardening: CohesionHardening::default(),
        };
        model.check_cutoff()?;
        Ok(model)
    }

    /// The same material with the cohesion hardening or softening `hardening`, or why it
    /// makes none: a softening steeper than the limit of a unique return (module docs), or a
    /// tension cut-off above the apex of the softened surface.
    pub fn with_hardening(mut self, hardening: CohesionHardening) -> Result<Self, String> {
        self.hardening = hardening;
        self.check_cutoff()?;
        if let Some(limit) = self.softening_limit().filter(|&l| hardening.modulus <= l) {
            return Err(format!(
                "softening modulus H = {} is steeper than this Mohr-Coulomb material allows \
                 (H > {limit:.6e}: beyond it the return is not unique)",
                hardening.modulus
            ));
        }
        Ok(self)
    }

    /// A cut-off must lie below the apex `c cot φ` of the weakest surface the cohesion reaches.
    fn check_cutoff(&self) -> Result<(), String> {
        let Some(t) = self.tension_cutoff else {
            return Ok(());
        };
        if !(t >= 0.0 && t.is_finite()) {
            return Err(format!("tension cut-off must be zero or positive, got {t}"));
        }
        let weakest = self.hardening.lowest(self.cohesion);
        if self.friction > 0.0 && t > weakest / self.friction.tan() {
            let which = if self.hardening.softens() {
                "of the softened surface, c_residual cot(phi)"
            } else {
                "c cot(phi)"
            };
            return Err(format!(
                "tension cut-off {t} exceeds the apex {which} = {}: it would cut nothing",
                weakest / self.friction.tan()
            ));
        }
        Ok(())
    }

    /// `k = √(((1 + sin ψ)² + 2 (1 − sin ψ)²)/3)`: the equivalent plastic strain per unit sum
    /// of the Mohr–Coulomb multipliers, `Δε̄_p = k Σ Δγ_i`, which is `√(2/3) ‖Δε_p‖` in triaxial
    /// compression (module docs).
    pub fn strain_per_multiplier(&self) -> f64 {
        let s = self.dilation.sin();
        (((1.0 + s).powi(2) + 2.0 * (1.0 - s).powi(2)) / 3.0).sqrt()
    }

    /// The most negative `H` with a unique return (module docs), if any bounds it: over the
    /// plane, both edges and the apex, `1 + h 1ᵀ M₀⁻¹ 1 > 0` with `h = 2 cos φ k H`, and at the
    /// apex beyond the planes' sets (ψ > 0) `1 + cot φ k H/(2K sin ψ) > 0`.
    pub fn softening_limit(&self) -> Option<f64> {
        let (planes, _) = self.planes(self.cohesion);
        let de = elasticity(&self.elastic);
        let k = self.strain_per_multiplier();
        let mut weights = Vec::new();
        // Φ_13 (index 1) with Φ_12 (0) and Φ_23 (3): the plane, the edges, the apex
        for set in [&[1][..], &[1, 0], &[1, 3], &[1, 0, 3]] {
            let n = set.len();
            let m = nalgebra::DMatrix::from_fn(n, n, |i, j| {
                planes[set[i]].normal.dot(&(de * planes[set[j]].flow))
            });
            // dependent planes (the apex of ψ = 0) have no return of their own: skipped as in
            // `return_to`
            let size = m.abs().max();
            if m.determinant().abs() <= 1e-10 * size.powi(n as i32) {
                continue;
            }
            if let Some(inverse) = m.try_inverse() {
                weights.push(2.0 * self.friction.cos() * k * inverse.sum());
            }
        }
        if self.friction > 0.0 && self.dilation > 0.0 {
            let (bulk, _) = bulk_and_shear(&self.elastic);
            weights.push(k / (self.friction.tan() * 2.0 * bulk * self.dilation.sin()));
        }
        weights
            .into_iter()
            .filter(|&w| w > 0.0)
            .map(|w| -1.0 / w)
            .reduce(f64::max)
    }

    /// The planes of the surface at the cohesion `cohesion`: the six Mohr–Coulomb planes, then
    /// the cut-off's three.
    fn planes(&self, cohesion: f64) -> ([Plane; 9], usize) {
        let (sin_phi, sin_psi) = (self.friction.sin(), self.dilation.sin());
        let level = 2.0 * cohesion * self.friction.cos();
        let unit = |i: usize| Vector3::from_fn(|k, _| if k == i { 1.0 } else { 0.0 });
        let mut planes = [Plane {
            normal: Vector3::zeros(),
            flow: Vector3::zeros(),
            level: 0.0,
            hardens: false,
        }; 9];
        let mut count = 0;
        for i in 0..3 {
            for j in 0..3 {
                if i != j {
                    let (difference, sum) = (unit(i) - unit(j), unit(i) + unit(j));
                    planes[count] = Plane {
                        normal: difference + sum * sin_phi,
                        flow: difference + sum * sin_psi,
                        level,
                        hardens: true,
                    };
                    count += 1;
                }
            }
        }
        if let Some(t) = self.tension_cutoff {
            for i in 0..3 {
                planes[count] = Plane {
                    normal: unit(i),
                    flow: unit(i),
                    level: t,
                    hardens: false,
                };
                count += 1;
            }
        }
        (planes, count)
    }

    /// The principal-space multi-surface return from the committed equivalent plastic strain
    /// `plastic_strain` (module docs).
    pub fn return_map(
        &self,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        plastic_strain: f64,
    ) -> Result<PrincipalReturn, String> {
        let cohesion = self.hardening.cohesion_at(self.cohesion, plastic_strain);
        let (planes, count) = self.planes(cohesion);
        let tolerance = 1e-10 * (self.cohesion + trial_stress.amax());
        if planes[..count]
            .iter()
            .all(|p| p.normal.dot(trial_stress) - p.level <= tolerance)
        {
            return Ok(PrincipalReturn::elastic(&self.elastic, *trial_stress));
        }
        self.hardening
            .return_on(self.cohesion, plastic_strain, |cohesion, slope| {
                self.plastic_return(strain, trial_stress, cohesion, slope, tolerance)
            })
    }

    /// The multi-surface return with the cohesion `cohesion + slope Δε̄_p` (module docs).
    fn plastic_return(
        &self,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        cohesion: f64,
        slope: f64,
        tolerance: f64,
    ) -> Result<PrincipalReturn, String> {
        let (planes, count) = self.planes(cohesion);
        let planes = &planes[..count];
        let k = self.strain_per_multiplier();
        // the rise of a Mohr–Coulomb plane's level per unit multiplier of any of them
        let rise = 2.0 * self.friction.cos() * k * slope;
        let de = elasticity(&self.elastic);
        let multiplier_scale = (self.cohesion + trial_stress.amax()) / de[(0, 0)];
        for size in 1..=3 {
            for set in subsets(count, size) {
                let set = &set[..size];
                let Some((stress, tangent, multipliers)) =
                    return_to(planes, set, &de, trial_stress, rise)
                else {
                    continue;
                };
                let consistent = multipliers.as_slice()[..size]
                    .iter()
                    .all(|&m| m >= -1e-10 * multiplier_scale);
                let increment = k * set
                    .iter()
                    .zip(multipliers.iter())
                    .filter(|(index, _)| planes[**index].hardens)
                    .map(|(_, m)| m)
                    .sum::<f64>();
                let raised = 2.0 * self.friction.cos() * slope * increment;
                let admissible = planes.iter().all(|p| {
                    let level = p.level + if p.hardens { raised } else { 0.0 };
                    p.normal.dot(&stress) - level <= tolerance
                });
                if consistent && admissible {
                    return Ok(PrincipalReturn {
                        stress,
                        tangent,
                        pair_modulus: None,
                        yielding: true,
                        plastic_strain_increment: Some(increment),
                    });
                }
            }
        }
        // Non-associated flow beyond the apex, where the apex's multipliers may have either
        // sign: the apex itself (the cut-off's corner `t 1` if there is one, where `D = 0`).
        let (mean, tangent, increment) = match self.tension_cutoff {
            Some(t) => (t, Matrix3::zeros(), 0.0),
            None if self.friction > 0.0 => {
                let cot = 1.0 / self.friction.tan();
                let (bulk, _) = bulk_and_shear(&self.elastic);
                let p_trial = bulk * strain.sum();
                if self.dilation > 0.0 {
                    // Δε̄_p = k Δε_v^p/(2 sin ψ), p = p^tr − K Δε_v^p = cot φ c(ε̄_p^n + Δε̄_p)
                    let per_volume = k / (2.0 * bulk * self.dilation.sin());
                    let g = cot * slope * per_volume;
                    let mean = (cot * cohesion + g * p_trial) / (1.0 + g);
                    let modulus = g * bulk / (1.0 + g);
                    (
                        mean,
                        Matrix3::from_element(modulus),
                        per_volume * (p_trial - mean),
                    )
                } else {
                    // no volumetric flow: the deviator removed, Δε̄_p = √(2/3) ‖dev ε^tr‖
                    let e = deviator(strain);
                    let norm = e.norm();
                    let n = if norm > 0.0 {
                        e / norm
                    } else {
                        Vector3::zeros()
                    };
                    let root = (2.0 / 3.0f64).sqrt();
                    let increment = root * norm;
                    (
                        cot * (cohesion + slope * increment),
                        Vector3::repeat(1.0) * n.transpose() * (cot * slope * root),
                        increment,
                    )
                }
            }
            None => {
                return Err(format!(
                    "the Mohr-Coulomb return found no admissible stress from the trial {trial_stress:?}"
                ));
            }
        };
        Ok(PrincipalReturn {
            stress: Vector3::repeat(mean),
            tangent,
            pair_modulus: Some(0.0),
            yielding: true,
            plastic_strain_increment: Some(increment),
        })
    }
}

/// The index sets of `size` (1 to 3) planes out of `count`, in lexicographic order (unused
/// slots zero).
fn subsets(count: usize, size: usize) -> Vec<[usize; 3]> {
    let mut sets = Vec::new();
    for i in 0..count {
        if size == 1 {
            sets.push([i, 0, 0]);
            continue;
        }
        for j in i + 1..count {
            if size == 2 {
                sets.push([i, j, 0]);
                continue;
            }
            for k in j + 1..count {
                sets.push([i, j, k]);
            }
        }
    }
    sets
}

/// The return to the planes `set` (module docs), the level of every Mohr–Coulomb plane rising
/// by `rise` per unit multiplier of each Mohr–Coulomb plane in the set: the stress, `D`, and
/// the multipliers; `None` if the planes are dependent (parallel planes, or three planes
/// without a common point).
fn return_to(
    planes: &[Plane],
    set: &[usize],
    de: &Matrix3<f64>,
    trial_stress: &Vector3<f64>,
    rise: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>, Vector3<f64>)> {
    let n = set.len();
    // A (normals) and B (flows) as 3 x n, padded with zero columns; M padded with the identity.
    let mut a = Matrix3::zeros();
    let mut b = Matrix3::zeros();
    let mut residual = Vector3::zeros();
    for (column, &index) in set.iter().enumerate() {
        let plane = &planes[index];
        a.set_column(column, &plane.normal);
        b.set_column(column, &plane.flow);
        residual[column] = plane.normal.dot(trial_stress) - plane.level;
    }
    let mut m = a.transpose() * de * b;
    for (i, &row) in set.iter().enumerate() {
        for (j, &column) in set.iter().enumerate() {
            if planes[row].hardens && planes[column].hardens {
                m[(i, j)] += rise;
            }
        }
    }
    // The n planes are dependent when the determinant is small against the n-th power of the
    // n x n block's entries (measured before the padding, whose unit diagonal adds nothing to
    // the determinant and would make the test depend on the units of stress; the cube of every
    // entry rejected every single plane once E was about 1e5 and sent those trials to an edge
    // or the apex).
    let size = m.abs().max();
    for k in n..3 {
        m[(k, k)] = 1.0;
    }
    let determinant = m.determinant();
    if determinant.abs() <= 1e-10 * size.powi(n as i32) || !determinant.is_finite() {
        return None;
    }
    let inverse = m.try_inverse()?;
    let multipliers = inverse * residual;
    let stress = trial_stress - de * b * multipliers;
    // the padding rows and columns of B and A are zero: they add nothing to D
    let tangent = de - de * b * inverse * a.transpose() * de;
    Some((stress, tangent, multipliers))
}

impl Material for MohrCoulomb {
    type History = PlasticHistory;
    const MODEL: &'static str = "mohr_coulomb";

    fn parameters() -> Vec<ParameterSpec> {
        let mut parameters = strength_parameters();
        parameters.push(ParameterSpec {
            name: "tension_cutoff",
            meaning: "tensile strength of a Rankine cut-off, at most c cot(phi) (default none)",
            label: Some("tension cut-off"),
            kind: ParameterKind::Number(Range::NonNegative),
            required: false,
        });
        parameters
    }

    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        if let Some(key) = SOFTENING_OPTIONS
            .into_iter()
            .find(|key| parameters.get(key).is_some())
        {
            return Err(format!(
                "{key} (the exponential softening of c, phi and psi) is not implemented for mohr_coulomb: use drucker_prager for it, or the linear cohesion softening H < 0 with c_residual"
            ));
        }
        let strength = read_strength(parameters)?;
        Self::new(
            strength.elastic,
            strength.cohesion,
            strength.friction,
            strength.dilation,
            parameters.optional_number("tension_cutoff")?,
        )?
        .with_hardening(strength.hardening)
    }

    fn describe() -> &'static str {
        "Mohr-Coulomb elasto-plasticity at finite strain (perfect, or linear hardening/softening of the cohesion down to a residual; returns to the plane, the edges and the apex, associated or not), optional tension cut-off"
    }

    elastoplastic::elastoplastic_material_methods!();

    fn tangent_is_symmetric(&self) -> bool {
        self.dilation == self.friction
    }
}

impl elastoplastic::PrincipalReturnMap for MohrCoulomb {
    fn elasticity(&self) -> &Hencky {
        &self.elastic
    }

    fn principal_return(
        &self,
        strain: &Vector3<f64>,
        stress: &Vector3<f64>,
        alpha: f64,
    ) -> Result<PrincipalReturn, String> {
        self.return_map(strain, stress, alpha)
    }
}
