//! The shipped triaxial scene (`scripts/triaxial_softening.rhai`) run as a user runs it, through
//! the command line, at two resolutions: every step's axial stress in its `history.csv` against
//! the homogeneous closed form of drained triaxial compression with a hardening or softening
//! cohesion (docs/plasticity.md, "A triaxial test with a known answer"), for Mohr–Coulomb and
//! the outer Drucker–Prager cone, which coincide in triaxial compression.

mod common;

use std::collections::HashMap;
use std::path::Path;

/// The scene's material and loading (its defaults).
const E: f64 = 1000.0;
const NU: f64 = 0.3;
const C0: f64 = 1.0;
const PHI: f64 = 30.0;
const PSI: f64 = 10.0;
const CONFINING: f64 = 5.0;
const SHORTENING: f64 = 0.1;

/// The homogeneous drained triaxial state at an axial logarithmic strain: the lateral
/// logarithmic strain, the Kirchhoff stresses and the accumulated plastic strain.
#[derive(Clone, Copy, Debug)]
struct TriaxialState {
    lateral_strain: f64,
    axial_kirchhoff: f64,
    lateral_kirchhoff: f64,
    plastic_multiplier: f64,
}

/// The closed form (docs/plasticity.md, "A triaxial test with a known answer"), independent of
/// the crate's material code. In principal Hencky measures the problem is small-strain
/// plasticity: `τ = D_e (ε − γ m)` in (axial, lateral) components, `m = (−(1 − sin ψ),
/// (1 + sin ψ)/2)` the flow of the compressive edge per unit multiplier (both planes'
/// multipliers equal), `ε̄_p = k γ`, `k = √(((1 + sin ψ)² + 2 (1 − sin ψ)²)/3)`, the yield
/// condition `τ_r (1 + sin φ) − τ_a (1 − sin φ) = 2 c(ε̄_p) cos φ` with
/// `c = max(c0 + H ε̄_p, c_res)` (no lower bound for `H ≥ 0`), and the sides' dead traction
/// `τ_r = −p λ_r = −p exp(ε_r)`. Given `ε_a` and the multiplier of the step before (monotonic
/// loading), the multiplier follows from the linear yield condition and `ε_r` from the lateral
/// balance, which is monotonic in `ε_r` (bisection).
///
/// With `strength: Strength::VonMises(..)` the soil is von Mises (`--set model=von_mises`):
/// isochoric flow `m = (−1, ½)` per unit multiplier, `ε̄_p = γ` (`√(2/3) ‖(−1, ½, ½)‖ = 1`), the
/// yield condition `τ_r − τ_a = σ_y(ε̄_p)` with the law written out here; its residual falls
/// strictly in γ while `3G + H(ε̄_p) > 0`, so the same bisections apply.
struct ClosedForm {
    strength: Strength,
}

/// The soil's strength law (the scene's defaults where not given).
#[derive(Clone, Copy, Debug)]
enum Strength {
    /// Mohr–Coulomb or the outer cone: `c = max(c0 + H ε̄_p, c_res)` (no bound for `H ≥ 0`).
    Cohesion { hardening: f64, residual: f64 },
    /// von Mises, `σ_y0 = √3 s_u`.
    VonMises(YieldLaw),
    /// The outer cone with the exponential softening of Yerro et al. (2016):
    /// `x = x_r + (x_p − x_r) e^{−rate ε̄_p}` for `c` (to `cohesion`) and `φ` (to `friction`,
    /// degrees); ψ held.
    Exponential {
        rate: f64,
        cohesion: f64,
        friction: f64,
    },
}

/// von Mises's yield stress laws (`material::hardening`'s, written out independently).
#[derive(Clone, Copy, Debug)]
enum YieldLaw {
    /// `σ_y0 + (σ_∞ − σ_y0)(1 − e^{−δ ε̄_p}) + H ε̄_p`.
    Voce {
        saturation: f64,
        rate: f64,
        modulus: f64,
    },
    /// `σ_y0 (r + (1 − r) e^{−3 √3 ε̄_p/ξ95})`.
    ExponentialSoftening { ratio: f64, xi95: f64 },
}

/// The scene's undrained strength (`s_u`) of the von Mises soil.
const S_U: f64 = 5.0;

impl YieldLaw {
    fn yield_stress(&self, eps_p: f64) -> f64 {
        let initial = 3.0f64.sqrt() * S_U;
        match *self {
            YieldLaw::Voce {
                saturation,
                rate,
                modulus,
            } => initial + (saturation - initial) * (1.0 - (-rate * eps_p).exp()) + modulus * eps_p,
            YieldLaw::ExponentialSoftening { ratio, xi95 } => {
                let xi = 3.0f64.sqrt() * eps_p;
                initial * (ratio + (1.0 - ratio) * (-3.0 * xi / xi95).exp())
            }
        }
    }
}

impl ClosedForm {
    fn moduli() -> (f64, f64) {
        let bulk = E / (3.0 * (1.0 - 2.0 * NU));
        let shear = E / (2.0 * (1.0 + NU));
        (bulk + 4.0 * shear / 3.0, bulk - 2.0 * shear / 3.0)
    }

    /// τ_a, τ_r of the elastic strains (e_a, e_r).
    fn stress(e_a: f64, e_r: f64) -> (f64, f64) {
        let (m, l) = Self::moduli();
        (m * e_a + 2.0 * l * e_r, l * e_a + (m + l) * e_r)
    }

    fn cohesion(hardening: f64, residual: f64, eps_p: f64) -> f64 {
        let c = C0 + hardening * eps_p;
        if hardening < 0.0 { c.max(residual) } else { c }
    }

    /// The flow `(m_a, m_r)` per unit multiplier and `k = ε̄_p/γ`.
    fn flow(&self) -> (f64, f64, f64) {
        if let Strength::VonMises(_) = self.strength {
            return (-1.0, 0.5, 1.0);
        }
        let s = PSI.to_radians().sin();
        let k = (((1.0 + s).powi(2) + 2.0 * (1.0 - s).powi(2)) / 3.0).sqrt();
        (-(1.0 - s), 0.5 * (1.0 + s), k)
    }

    fn yield_function(&self, tau: (f64, f64), eps_p: f64) -> f64 {
        match self.strength {
            Strength::Cohesion {
                hardening,
                residual,
            } => {
                let (sin, cos) = PHI.to_radians().sin_cos();
                tau.1 * (1.0 + sin)
                    - tau.0 * (1.0 - sin)
                    - 2.0 * cos * Self::cohesion(hardening, residual, eps_p)
            }
            Strength::VonMises(law) => tau.1 - tau.0 - law.yield_stress(eps_p),
            Strength::Exponential {
                rate,
                cohesion,
                friction,
            } => {
                let decay = (-rate * eps_p).exp();
                let phi = friction + (PHI - friction) * decay;
                let c = cohesion + (C0 - cohesion) * decay;
                let (sin, cos) = phi.to_radians().sin_cos();
                tau.1 * (1.0 + sin) - tau.0 * (1.0 - sin) - 2.0 * cos * c
            }
        }
    }

    /// The multiplier γ ≥ `gamma_before` on the yield surface at the total strains (elastic:
    /// `gamma_before`).
    fn multiplier(&self, e_a: f64, e_r: f64, gamma_before: f64) -> f64 {
        let (m_a, m_r, k) = self.flow();
        let at = |gamma: f64| {
            let tau = Self::stress(e_a - gamma * m_a, e_r - gamma * m_r);
            self.yield_function(tau, k * gamma)
        };
        if at(gamma_before) <= 0.0 {
            return gamma_before;
        }
        // decreasing in γ (the unique-return limit): bisection
        let (mut low, mut high) = (gamma_before, gamma_before + 1.0);
        assert!(at(high) < 0.0);
        for _ in 0..200 {
            let mid = 0.5 * (low + high);
            if at(mid) > 0.0 { low = mid } else { high = mid }
        }
        0.5 * (low + high)
    }

    fn state(&self, axial_strain: f64, gamma_before: f64) -> TriaxialState {
        let (m_a, m_r, _) = self.flow();
        let solve = |e_r: f64| {
            let gamma = self.multiplier(axial_strain, e_r, gamma_before);
            let tau = Self::stress(axial_strain - gamma * m_a, e_r - gamma * m_r);
            (gamma, tau)
        };
        let balance = |e_r: f64| solve(e_r).1.1 + CONFINING * e_r.exp();
        let (mut low, mut high) = (-0.5, 0.5);
        assert!(balance(low) < 0.0 && balance(high) > 0.0);
        for _ in 0..200 {
            let mid = 0.5 * (low + high);
            if balance(mid) > 0.0 {
                high = mid
            } else {
                low = mid
            }
        }
        let e_r = 0.5 * (low + high);
        let (gamma, tau) = solve(e_r);
        TriaxialState {
            lateral_strain: e_r,
            axial_kirchhoff: tau.0,
            lateral_kirchhoff: tau.1,
            plastic_multiplier: gamma,
        }
    }

    /// The states after each of `steps` equal steps of the top to `SHORTENING`.
    fn path(&self, steps: usize) -> Vec<TriaxialState> {
        let mut gamma = 0.0;
        (1..=steps)
            .map(|k| {
                let stretch = 1.0 - SHORTENING * k as f64 / steps as f64;
                let state = self.state(stretch.ln(), gamma);
                gamma = state.plastic_multiplier;
                state
            })
            .collect()
    }
}

/// `history.csv` as columns by name.
fn history(dir: &Path) -> HashMap<String, Vec<f64>> {
    let text = std::fs::read_to_string(dir.join("history.csv")).unwrap();
    let mut lines = text.lines();
    let names: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let mut columns: HashMap<String, Vec<f64>> = HashMap::new();
    for line in lines {
        for (name, value) in names.iter().zip(line.split(',')) {
            let value = value.parse().unwrap_or(f64::NAN);
            columns.entry(name.clone()).or_default().push(value);
        }
    }
    columns
}

/// Runs the shipped scene through the command line with `set`; returns its history and what
/// it printed on stderr.
fn run_scene(set: &[(&str, &str)], tag: &str) -> (HashMap<String, Vec<f64>>, String) {
    let dir = common::temp_dir("triaxial", tag);
    let scene = common::shipped_scene("triaxial_softening.rhai");
    let mut args: Vec<String> = vec!["run".into(), scene.display().to_string()];
    for (name, value) in set {
        args.push("--set".into());
        args.push(format!("{name}={value}"));
    }
    args.push("--out".into());
    args.push(dir.display().to_string());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let output = common::impm(&args);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "impm {args:?} failed:\n{stderr}");
    let columns = history(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    (columns, stderr)
}

/// Relative tolerance on the stresses (of the peak axial stress): Newton's tolerance is 1e-9
/// of the load scale.
const TOLERANCE: f64 = 1e-7;

/// Every step of `model` with hardening `h` (and `residual`) at 1 and 2 elements per side
/// against the closed form; returns the closed form's states (for the callers' checks of what
/// the path reached) and the runs' stderr.
fn follows_the_closed_form(model: &str, h: f64, residual: f64) -> (Vec<TriaxialState>, String) {
    let (h_text, r_text) = (format!("{h:?}"), format!("{residual:?}"));
    let strength = Strength::Cohesion {
        hardening: h,
        residual,
    };
    let set = [
        ("model", model),
        ("H", h_text.as_str()),
        ("c_residual", r_text.as_str()),
    ];
    runs_follow(strength, &set, &format!("{model}{h}"))
}

/// Every step of the scene with `set` at 1 and 2 elements per side against the closed form of
/// `strength`; returns the closed form's states and the runs' stderr.
fn runs_follow(
    strength: Strength,
    set: &[(&str, &str)],
    tag: &str,
) -> (Vec<TriaxialState>, String) {
    let steps = 20;
    let closed_form = ClosedForm { strength };
    let reference = closed_form.path(steps);
    let scale = reference
        .iter()
        .map(|s| s.axial_kirchhoff.abs())
        .fold(0.0, f64::max);
    let mut stderr = String::new();
    for cells in ["1", "2"] {
        let mut with_cells = set.to_vec();
        with_cells.extend([("cells", cells), ("steps", "20")]);
        let (columns, err) = run_scene(&with_cells, &format!("{tag}{cells}"));
        stderr += &err;
        let column = |name: &str| {
            let c = columns
                .get(name)
                .unwrap_or_else(|| panic!("no column {name}"));
            assert_eq!(c.len(), steps, "{name}");
            c.clone()
        };
        let (axial_stretch, lateral_stretch) = (column("axial_stretch"), column("lateral_stretch"));
        let (axial, lateral) = (column("axial_stress"), column("lateral_stress"));
        let (other_lateral, force) = (column("centre_F_yy"), column("top_force"));
        let mut worst: f64 = 0.0;
        for (k, exact) in reference.iter().enumerate() {
            let prescribed = 1.0 - SHORTENING * (k + 1) as f64 / steps as f64;
            assert!(
                (axial_stretch[k] - prescribed).abs() < 1e-12,
                "step {}",
                k + 1
            );
            assert!((other_lateral[k] - lateral_stretch[k]).abs() < 1e-12);
            let jacobian = axial_stretch[k] * lateral_stretch[k].powi(2);
            // history.csv: Cauchy stresses, compression positive; τ = J σ
            let tau_a = -jacobian * axial[k];
            let tau_r = -jacobian * lateral[k];
            let errors = [
                (tau_a - exact.axial_kirchhoff).abs() / scale,
                (tau_r - exact.lateral_kirchhoff).abs() / scale,
                (lateral_stretch[k].ln() - exact.lateral_strain).abs(),
                // the platen's force is the axial Cauchy stress on the current area
                (force[k] - axial[k] * lateral_stretch[k].powi(2)).abs() / scale,
            ];
            let error = errors.iter().copied().fold(0.0, f64::max);
            assert!(
                error < TOLERANCE,
                "{set:?}, {cells} cells, step {}: τ_a {tau_a} against {}, τ_r {tau_r} \
                 against {}, errors {errors:?}",
                k + 1,
                exact.axial_kirchhoff,
                exact.lateral_kirchhoff,
            );
            worst = worst.max(error);
        }
        println!("{set:?}, {cells} cells: largest error {worst:.2e} of {scale:.4}");
    }
    (reference, stderr)
}

/// The frictional soils' `ε̄_p` (`k γ`).
fn plastic_strain(state: &TriaxialState) -> f64 {
    let frictional = ClosedForm {
        strength: Strength::Cohesion {
            hardening: 0.0,
            residual: 0.0,
        },
    };
    frictional.flow().2 * state.plastic_multiplier
}

/// Hardening (`H = 100`): the axial stress rises past the first yield along the hardened
/// edge; both models, 1 and 2 elements per side, every step within 1e-7 of the peak. No
/// softening warning.
#[test]
fn triaxial_hardening_follows_the_closed_form_at_two_resolutions() {
    for model in ["mohr_coulomb", "drucker_prager"] {
        let (reference, stderr) = follows_the_closed_form(model, 100.0, 0.0);
        let yielded = reference
            .iter()
            .filter(|s| s.plastic_multiplier > 0.0)
            .count();
        assert!(yielded >= 15, "{yielded} plastic steps");
        let last = reference.last().unwrap();
        let c_end = C0 + 100.0 * plastic_strain(last);
        assert!(c_end > 1.5 * C0, "the cohesion hardened to {c_end}");
        assert!(!stderr.contains("mesh-dependent"), "{stderr}");
    }
}

/// Softening to the residual (`H = −20`, `c_residual = 0.2`): through the peak, past the kink
/// at `ε̄_p = 0.04` and on the residual plateau; both models, 1 and 2 elements per side, every
/// step within 1e-7 of the peak; the run is warned that softening is mesh-dependent.
#[test]
fn triaxial_softening_follows_the_closed_form_through_the_peak_to_the_residual() {
    for model in ["mohr_coulomb", "drucker_prager"] {
        let (reference, stderr) = follows_the_closed_form(model, -20.0, 0.2);
        let peak = peak_of(&reference);
        let kink = (1.0 - 0.2) / 20.0;
        let residual_steps = reference
            .iter()
            .filter(|s| plastic_strain(s) > kink + 1e-9)
            .count();
        let softening_steps = reference
            .iter()
            .filter(|s| s.plastic_multiplier > 0.0 && plastic_strain(s) < kink)
            .count();
        println!(
            "{model}: peak at step {}, {softening_steps} steps softening, {residual_steps} on the residual",
            peak + 1
        );
        assert!(
            peak + 1 < reference.len() && peak > 0,
            "peak at step {}",
            peak + 1
        );
        assert!(softening_steps >= 2, "{softening_steps} steps softening");
        assert!(
            residual_steps >= 3,
            "{residual_steps} steps on the residual"
        );
        assert!(
            stderr.contains("mesh-dependent") && stderr.contains("soil"),
            "no softening warning naming the material:\n{stderr}"
        );
    }
}

/// The index of the step with the largest axial compression.
fn peak_of(reference: &[TriaxialState]) -> usize {
    (0..reference.len())
        .max_by(|&a, &b| {
            let (a, b) = (reference[a].axial_kirchhoff, reference[b].axial_kirchhoff);
            b.partial_cmp(&a).unwrap()
        })
        .unwrap()
}

/// Undrained clay (`--set model=von_mises`, `s_u = 5`) whose strength softens exponentially
/// with the plastic shear strain (`exponential_softening`, `residual_ratio = 0.3`, `xi95 =
/// 0.2`): every step at 1 and 2 elements per side within 1e-7 of the closed form, through the
/// peak deep into the softening (more than 90 % of the strength lost to the residual by the
/// end); the run is warned that softening is mesh-dependent.
#[test]
fn triaxial_von_mises_softening_follows_the_closed_form_deep_into_the_softening() {
    let law = YieldLaw::ExponentialSoftening {
        ratio: 0.3,
        xi95: 0.2,
    };
    let (reference, stderr) = runs_follow(
        Strength::VonMises(law),
        &[("model", "von_mises"), ("law", "exponential_softening")],
        "vm_soft",
    );
    let peak = peak_of(&reference);
    let last = reference.last().unwrap();
    let initial = 3.0f64.sqrt() * S_U;
    let lost = (initial - law.yield_stress(last.plastic_multiplier)) / (initial * (1.0 - 0.3));
    println!(
        "von Mises softening: peak at step {}, {:.1} % of the softening done at the end (ε̄_p = {:.4})",
        peak + 1,
        100.0 * lost,
        last.plastic_multiplier
    );
    assert!(
        peak > 0 && peak + 5 < reference.len(),
        "peak at step {}",
        peak + 1
    );
    assert!(lost > 0.9, "{lost}");
    assert!(
        stderr.contains("mesh-dependent") && stderr.contains("soil"),
        "no softening warning naming the material:\n{stderr}"
    );
}

/// Voce saturation hardening of the von Mises soil (`law = "voce"`, `sigma_inf = 15`,
/// `delta = 30`, `H = 2`): every step at 1 and 2 elements per side within 1e-7 of the closed
/// form, to within 10 % of the saturation; no softening warning.
#[test]
fn triaxial_von_mises_voce_hardening_follows_the_closed_form_to_saturation() {
    let law = YieldLaw::Voce {
        saturation: 15.0,
        rate: 30.0,
        modulus: 2.0,
    };
    let (reference, stderr) = runs_follow(
        Strength::VonMises(law),
        &[("model", "von_mises"), ("law", "voce"), ("H", "2.0")],
        "vm_voce",
    );
    let last = reference.last().unwrap();
    let initial = 3.0f64.sqrt() * S_U;
    let exponential_part =
        law.yield_stress(last.plastic_multiplier) - 2.0 * last.plastic_multiplier;
    let saturated = (exponential_part - initial) / (15.0 - initial);
    let yielded = reference
        .iter()
        .filter(|s| s.plastic_multiplier > 0.0)
        .count();
    println!(
        "von Mises voce: {yielded} plastic steps, {:.1} % saturated at the end",
        100.0 * saturated
    );
    assert!(yielded >= 15 && saturated > 0.9, "{yielded}, {saturated}");
    assert_eq!(peak_of(&reference) + 1, reference.len());
    assert!(!stderr.contains("mesh-dependent"), "{stderr}");
}

/// The exponential softening of cohesion and friction of the outer Drucker–Prager cone
/// (`--set model=drucker_prager --set softening_rate=20 --set phi_residual=20`, `c_residual`
/// 0.2; Yerro et al. 2016): every step at 1 and 2 elements per side within 1e-7 of the closed
/// form with `c(ε̄_p)` and `φ(ε̄_p)`, through the peak and well into the softening (the axial
/// stress at the end below 75 % of the peak, the parameters more than half-way to their
/// residuals). Mohr–Coulomb refuses the option by name.
#[test]
fn triaxial_friction_and_cohesion_softening_follows_the_closed_form() {
    let strength = Strength::Exponential {
        rate: 20.0,
        cohesion: 0.2,
        friction: 20.0,
    };
    let set = [
        ("model", "drucker_prager"),
        ("softening_rate", "20.0"),
        ("phi_residual", "20.0"),
        ("c_residual", "0.2"),
    ];
    let (reference, stderr) = runs_follow(strength, &set, "dp-exponential");
    let peak = peak_of(&reference);
    let end = reference.last().unwrap();
    let eps_p = plastic_strain(end);
    println!(
        "peak τ_a {:.4} at step {}, end {:.4}, ε̄_p {eps_p:.4}, e^(−20 ε̄_p) = {:.3}",
        reference[peak].axial_kirchhoff,
        peak + 1,
        end.axial_kirchhoff,
        (-20.0 * eps_p).exp()
    );
    assert!(peak + 1 < reference.len() / 2, "peak at step {}", peak + 1);
    assert!(end.axial_kirchhoff.abs() < 0.75 * reference[peak].axial_kirchhoff.abs());
    assert!((-20.0 * eps_p).exp() < 0.5, "{eps_p}");
    assert!(stderr.contains("mesh-dependent"), "{stderr}");

    let dir = common::temp_dir("triaxial", "mc-exponential");
    let scene = common::shipped_scene("triaxial_softening.rhai");
    let scene = scene.display().to_string();
    let args = [
        "run",
        scene.as_str(),
        "--set",
        "softening_rate=20.0",
        "--out",
        dir.to_str().unwrap(),
    ];
    let output = common::impm(&args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("softening_rate") && stderr.contains("mohr_coulomb"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
