//! Mohr–Coulomb plasticity at finite strain (perfect plasticity), with an optional tension
//! cut-off.
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

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::drucker_prager::{check_strength, read_strength, strength_parameters};
use super::elastoplastic::{self, PlasticHistory, PrincipalReturn, elasticity};
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
}

/// One plane of the surface: yield normal `a`, flow direction `b`, `a · τ ≤ level`.
#[derive(Clone, Copy, Debug)]
struct Plane {
    normal: Vector3<f64>,
    flow: Vector3<f64>,
    level: f64,
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
        let friction = friction_degrees.to_radians();
        if let Some(t) = tension_cutoff {
            if !(t >= 0.0 && t.is_finite()) {
                return Err(format!("tension cut-off must be zero or positive, got {t}"));
            }
            if friction > 0.0 && t > cohesion / friction.tan() {
                return Err(format!(
                    "tension cut-off {t} exceeds the apex c cot(phi) = {}: it would cut nothing",
                    cohesion / friction.tan()
                ));
            }
        }
        Ok(Self {
            elastic,
            cohesion,
            friction,
            dilation: dilation_degrees.to_radians(),
            tension_cutoff,
        })
    }

    /// The planes of the surface: the six Mohr–Coulomb planes, then the cut-off's three.
    fn planes(&self) -> ([Plane; 9], usize) {
        let (sin_phi, sin_psi) = (self.friction.sin(), self.dilation.sin());
        let level = 2.0 * self.cohesion * self.friction.cos();
        let unit = |i: usize| Vector3::from_fn(|k, _| if k == i { 1.0 } else { 0.0 });
        let mut planes = [Plane {
            normal: Vector3::zeros(),
            flow: Vector3::zeros(),
            level: 0.0,
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
                };
                count += 1;
            }
        }
        (planes, count)
    }

    /// The principal-space multi-surface return (module docs).
    pub fn return_map(&self, trial_stress: &Vector3<f64>) -> Result<PrincipalReturn, String> {
        let (planes, count) = self.planes();
        let planes = &planes[..count];
        let scale = self.cohesion + trial_stress.amax();
        let tolerance = 1e-10 * scale;
        let admissible = |stress: &Vector3<f64>| {
            planes
                .iter()
                .all(|p| p.normal.dot(stress) - p.level <= tolerance)
        };
        if admissible(trial_stress) {
            return Ok(PrincipalReturn::elastic(&self.elastic, *trial_stress));
        }
        let de = elasticity(&self.elastic);
        let multiplier_scale = scale / de[(0, 0)];
        for size in 1..=3 {
            for set in subsets(count, size) {
                let Some((stress, tangent, multipliers)) =
                    return_to(planes, &set[..size], &de, trial_stress)
                else {
                    continue;
                };
                let consistent = multipliers.as_slice()[..size]
                    .iter()
                    .all(|&m| m >= -1e-10 * multiplier_scale);
                if consistent && admissible(&stress) {
                    return Ok(PrincipalReturn {
                        stress,
                        tangent,
                        pair_modulus: None,
                        yielding: true,
                    });
                }
            }
        }
        // Non-associated flow beyond the apex, where the apex's multipliers may have either
        // sign: the apex itself (the cut-off's corner `t 1` if there is one), where `D = 0`.
        let apex = match self.tension_cutoff {
            Some(t) => t,
            None if self.friction > 0.0 => self.cohesion / self.friction.tan(),
            None => {
                return Err(format!(
                    "the Mohr-Coulomb return found no admissible stress from the trial {trial_stress:?}"
                ));
            }
        };
        Ok(PrincipalReturn {
            stress: Vector3::repeat(apex),
            tangent: Matrix3::zeros(),
            pair_modulus: Some(0.0),
            yielding: true,
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

/// The return to the planes `set` (module docs): the stress, `D`, and the multipliers; `None`
/// if the planes are dependent (parallel planes, or three planes without a common point).
fn return_to(
    planes: &[Plane],
    set: &[usize],
    de: &Matrix3<f64>,
    trial_stress: &Vector3<f64>,
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
        let (elastic, cohesion, friction, dilation) = read_strength(parameters)?;
        Self::new(
            elastic,
            cohesion,
            friction,
            dilation,
            parameters.optional_number("tension_cutoff")?,
        )
    }

    fn describe() -> &'static str {
        "Mohr-Coulomb elasto-plasticity at finite strain (perfect plasticity, returns to the plane, the edges and the apex, associated or not), optional tension cut-off"
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
        _strain: &Vector3<f64>,
        stress: &Vector3<f64>,
        _alpha: f64,
    ) -> Result<PrincipalReturn, String> {
        self.return_map(stress)
    }
}
