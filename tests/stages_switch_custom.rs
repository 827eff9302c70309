//! `material_of` with a model written outside the crate, with its own history type
//! (`src/material/mod.rs`, "Handing a point over to another model"): the model says what it
//! hands over and what it takes through `Material::hand_over` / `Material::take_over`, and a
//! von Mises block switched to it and back carries its elastic strain and its plastic strain
//! through it; the homogeneous confined block's state after each stage is checked against its
//! closed form. A switch the model cannot take (from Hencky, which hands over no elastic
//! strain) is refused with the `material_of` line; the trait's default refuses a plastic
//! strain it would lose.

use impm::components::Trial;
use impm::effects::{self, materials::MaterialModule};
use impm::material::{
    CarriedState, Hencky, HistoryValues, Material, MaterialParameters, ParameterSpec,
    PlasticHistory, Response, VonMises, block, embed, symmetric_from_values, symmetric_values,
};
use impm::plugin::ModuleSet;
use impm::run::Simulation;
use impm::stages::PointHistory;
use nalgebra::{Matrix3, SMatrix};

mod common;

/// The history of [`ElasticStrain`]: the elastic logarithmic strain and the plastic strain it
/// was handed.
#[derive(Clone, Debug, Default, PartialEq)]
struct ElasticStrainHistory {
    /// `ε_e = ½ ln b_e` (3x3, symmetric; zero: undeformed).
    elastic_strain: Matrix3<f64>,
    /// The accumulated equivalent plastic strain handed over (kept, never grows).
    plastic_strain: f64,
}

/// `ε_e` (xx, yy, zz, xy, yz, xz), `ε̄_p`.
impl HistoryValues for ElasticStrainHistory {
    const LEN: usize = 7;

    fn write(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(&symmetric_values(&self.elastic_strain));
        out.push(self.plastic_strain);
    }

    fn read(values: &[f64]) -> Option<Self> {
        let (&plastic_strain, strain) = values.split_last()?;
        let elastic_strain = symmetric_from_values(strain)?;
        values.iter().all(|v| v.is_finite()).then_some(Self {
            elastic_strain,
            plastic_strain,
        })
    }
}

/// A model outside the crate with its own history: Hencky elasticity on the elastic
/// logarithmic strain it keeps, `τ = D_e ε_e`, `ε_e^tr = ½ ln(Δf exp(2 ε_e^n) Δfᵀ)` (an elastic
/// predictor that never flows: a plastic state held). It takes over the elastic left
/// Cauchy–Green tensor `b_e` (the strain, not the stress, is continuous; with the old model's
/// elasticity the stress is too) and the plastic strain; it hands both back.
#[derive(Clone, Debug, PartialEq)]
struct ElasticStrain {
    elastic: Hencky,
}

/// `exp(2 ε)` and `½ ln b` of symmetric tensors.
fn stretch_of(strain: &Matrix3<f64>) -> Matrix3<f64> {
    let eigen = strain.symmetric_eigen();
    let b = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(|e| (2.0 * e).exp()))
        * eigen.eigenvectors.transpose();
    (b + b.transpose()) * 0.5
}

fn strain_of(b: &Matrix3<f64>) -> Result<Matrix3<f64>, String> {
    let eigen = b.symmetric_eigen();
    if eigen
        .eigenvalues
        .iter()
        .any(|v| !(v.is_finite() && *v > 0.0))
    {
        return Err(format!("b_e is not positive definite: {b:?}"));
    }
    let e = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(|v| 0.5 * v.ln()))
        * eigen.eigenvectors.transpose();
    Ok((e + e.transpose()) * 0.5)
}

impl Material for ElasticStrain {
    type History = ElasticStrainHistory;
    const MODEL: &'static str = "elastic_strain";

    fn parameters() -> Vec<ParameterSpec> {
        Hencky::parameters()
    }

    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        Ok(Self {
            elastic: Hencky::from_parameters(parameters)?,
        })
    }

    fn describe() -> &'static str {
        "Hencky elasticity on a kept elastic strain, the plastic strain held (tests/stages_switch_custom.rs)"
    }

    fn respond<const D: usize>(
        &self,
        _deformation_gradient: &SMatrix<f64, D, D>,
        increment: &SMatrix<f64, D, D>,
        committed: &ElasticStrainHistory,
    ) -> Result<Response<D, ElasticStrainHistory>, String> {
        let df = embed(increment);
        let trial = df * stretch_of(&committed.elastic_strain) * df.transpose();
        let (kirchhoff, tangent) = self.elastic.try_kirchhoff_and_tangent::<D>(&trial)?;
        Ok(Response {
            kirchhoff,
            tangent,
            left_cauchy_green: block::<D>(&trial),
            history: ElasticStrainHistory {
                elastic_strain: strain_of(&trial)?,
                plastic_strain: committed.plastic_strain,
            },
        })
    }

    fn stiffness_scale(&self) -> f64 {
        self.elastic.youngs_modulus
    }

    fn hand_over(&self, committed: &ElasticStrainHistory, carried: CarriedState) -> CarriedState {
        CarriedState {
            elastic_left_cauchy_green: Some(stretch_of(&committed.elastic_strain)),
            plastic_strain: Some(committed.plastic_strain),
            ..carried
        }
    }

    fn take_over(&self, carried: &CarriedState) -> Result<ElasticStrainHistory, String> {
        let b = carried.elastic_left_cauchy_green.ok_or(
            "the 'elastic_strain' model takes the elastic left Cauchy–Green tensor b_e, which the old model does not hand over",
        )?;
        Ok(ElasticStrainHistory {
            elastic_strain: strain_of(&b)?,
            plastic_strain: carried.plastic_strain.unwrap_or(0.0),
        })
    }
}

fn modules() -> ModuleSet {
    effects::built_in().with(MaterialModule::<ElasticStrain>::default())
}

fn build(tag: &str, text: &str) -> Simulation<2> {
    let dir = common::temp_dir("stages-switch-custom", tag);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{tag}.rhai"));
    std::fs::write(&path, text).unwrap();
    let spec = modules()
        .load_scene(&path, &[])
        .unwrap_or_else(|e| panic!("{e}"));
    Simulation::<2>::with_modules(&spec, &dir.join("out"), &modules()).unwrap()
}

/// Young's modulus (ν = 0), the yield stress and the hardening modulus of the von Mises block.
const E: f64 = 1.0e6;
const SIGMA_Y: f64 = 100.0;
const H: f64 = 1.0e4;

/// The block 1 × 1 of `tests/stages_switch.rs` (plane strain, E = 1e6, ν = 0, quadratic
/// B-splines, 2 × 2 cells of a 2 × 3 grid, 3 × 3 Gauss points per cell, rollers at its base and
/// sides, a top traction of 32 points per cell) in three stages: "yield" (line 7), von Mises
/// (σ_y = 100, H = 1e4) under q = 55, 110; "held" (line 9): `material_of` (line 10) gives it
/// material `held` (`held`: its model) and q goes down by 40 λ, λ = 0, 0.5, 1; "back"
/// (line 12): `material_of` (line 13) gives it the first material again and q goes up by
/// 60 λ (to 130).
fn three_stages(held: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 1.5], cells: [2, 3], basis: \"bspline\", order: 2 }});\n\
         const first = material(#{{ name: \"first\", model: \"von_mises\", sigma_y: {SIGMA_Y:?}, H: {H:?}, E: {E:?}, nu: 0.0, density: 1.0 }});\n\
         const held = material(#{{ name: \"held\", model: \"{held}\", E: {E:?}, nu: 0.0, density: 1.0 }});\n\
         body(#{{ name: \"block\", material: first, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 3, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         stage(#{{ name: \"yield\", steps: 2 }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -110.0], per_cell: 32 }});\n\
         stage(#{{ name: \"held\", load_factors: [0.0, 0.5, 1.0] }});\n\
         material_of(#{{ body: \"block\", material: \"held\" }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, 40.0], per_cell: 32 }});\n\
         stage(#{{ name: \"back\", load_factors: [0.0, 0.5, 1.0] }});\n\
         material_of(#{{ body: \"block\", material: \"first\" }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -60.0], per_cell: 32 }});\n"
    )
}

/// The closed form of the confined block (ν = 0, plane strain, rollers: the only strain is the
/// vertical logarithmic strain ε) under the top pressure q (Cauchy: σ_yy = −q, so
/// τ_yy = −q J = −q e^ε). The plastic strain is deviatoric along the load,
/// ε_p = a (−1, ½, ½) in (yy, xx, zz), ε̄_p = a, so with λ = 0, G = E/2:
///
/// ```text
///   τ_yy = E (ε + a),   τ_xx = τ_zz = −E a / 2,   q_vm = τ_xx − τ_yy = −E (ε + 3a/2)
/// ```
///
/// Flowing (`held = None`): q_vm = σ_y + H a; held: a given. Returns (ε, a), ε by Newton's
/// method on E (ε + a(ε)) + q e^ε = 0.
fn confined(q: f64, held: Option<f64>) -> (f64, f64) {
    let a_of = |eps: f64| held.unwrap_or((-E * eps - SIGMA_Y) / (1.5 * E + H));
    let slope_a = if held.is_some() {
        0.0
    } else {
        -E / (1.5 * E + H)
    };
    let mut eps = -q / E;
    for _ in 0..50 {
        let residual = E * (eps + a_of(eps)) + q * eps.exp();
        let step = residual / (E * (1.0 + slope_a) + q * eps.exp());
        eps -= step;
        if step.abs() < 1e-17 {
            break;
        }
    }
    (eps, a_of(eps))
}

/// Every point's Kirchhoff stress and plastic strain (from the von Mises or the held model's
/// history), in `PointId` order.
fn states(sim: &mut Simulation<2>) -> Vec<(Matrix3<f64>, f64)> {
    common::point_states::<VonMises, ElasticStrain>(
        sim,
        |h: &PlasticHistory| h.plastic_strain,
        |h: &ElasticStrainHistory| h.plastic_strain,
    )
    .into_iter()
    .map(|(stress, e)| (stress, e.expect("every point has a history")))
    .collect()
}

/// The largest departure of every point from the closed form (ε, a) under q: of τ_yy and τ_xx
/// (= τ_zz), relative to σ_y, and of the plastic strain, relative to a.
fn from_closed_form(states: &[(Matrix3<f64>, f64)], q: f64, (eps, a): (f64, f64)) -> (f64, f64) {
    let (yy, xx) = (-q * eps.exp(), -E * a / 2.0);
    states
        .iter()
        .fold((0.0f64, 0.0f64), |(s, e), (tau, strain)| {
            let stress = [
                (tau[(1, 1)] - yy).abs(),
                (tau[(0, 0)] - xx).abs(),
                (tau[(2, 2)] - xx).abs(),
            ]
            .into_iter()
            .fold(0.0, f64::max);
            (s.max(stress / SIGMA_Y), e.max((strain - a).abs() / a))
        })
}

/// One step of both runs; the switched run's states, checked against the run not switched:
/// stresses within 1e-6 σ_y, plastic strains within 1e-9 (the first step after a switch
/// resolves the out-of-balance force Newton left at the stage's end with the new model's
/// tangent, elastic for the held model where von Mises flows on its surface: 2.9e-8 σ_y
/// measured; the other steps agree to round-off).
fn run_both(sim: &mut Simulation<2>, plain: &mut Simulation<2>) -> Vec<(Matrix3<f64>, f64)> {
    let record = sim.step().unwrap_or_else(|e| panic!("{e}")).clone();
    plain.step().unwrap();
    let (a, b) = (states(sim), states(plain));
    let worst = a.iter().zip(&b).fold((0.0f64, 0.0f64), |(s, e), (a, b)| {
        (s.max((a.0 - b.0).amax()), e.max((a.1 - b.1).abs()))
    });
    println!(
        "step {} ({} iterations): against the run not switched: stress {:.2e} σ_y, plastic strain {:.2e}",
        record.step,
        record.iterations,
        worst.0 / SIGMA_Y,
        worst.1
    );
    assert!(worst.0 < 1e-6 * SIGMA_Y, "step {}: {worst:?}", record.step);
    assert!(worst.1 < 1e-9, "step {}: {worst:?}", record.step);
    a
}

/// `now` against the closed form `exact` under `q`: stresses within 1e-7 σ_y, plastic strains
/// within 1e-6 of it.
fn check(what: &str, now: &[(Matrix3<f64>, f64)], q: f64, exact: (f64, f64)) {
    let (stress, strain) = from_closed_form(now, q, exact);
    println!(
        "{what}: q = {q}: closed form ε = {:.9e}, ε̄_p = {:.9e}; departures: stress {stress:.2e} σ_y, plastic strain {strain:.2e} (relative)",
        exact.0, exact.1
    );
    assert!(stress < 1e-7, "{what}: {stress:e}");
    assert!(strain < 1e-6, "{what}: {strain:e}");
}

/// The block yielded under von Mises (ε̄_p = a₁ ≈ 1.96e-5 at q = 110), switched to the held
/// model of this file, unloaded to q = 70, switched back to von Mises and loaded to q = 130.
/// Checked after each stage against the closed form ([`confined`]): every stress within
/// 1e-7 σ_y and every plastic strain within 1e-6 of it (relative). The hand-over itself, point
/// by point before the switch: von Mises's `b_e` and `ε̄_p` taken by the held model give its
/// stress back within 1e-10 σ_y (exp/log round-off) and the plastic strain bit for bit; after
/// the switch's first step (no new load) the stress within 1e-6 σ_y of the one before (the
/// out-of-balance force resolved elastically, see [`run_both`]). After "back" the hardened surface
/// σ_y + H a₁ is where the reloaded block flows again: had the plastic strain not come back,
/// von Mises would restart from ε̄_p = 0 and end near ε̄_p = a₃ − a₁ (the test prints both).
/// The whole path is also the run never switched (von Mises unloads elastically too), step by
/// step ([`run_both`]).
#[test]
fn a_model_outside_the_crate_carries_the_elastic_and_plastic_strain_through_a_switch() {
    let text = three_stages("elastic_strain");
    let mut sim = build("carry", &text);
    let plain_text = text.replace("material_of(", "// material_of(");
    let mut plain = build("carry-plain", &plain_text);
    // stage "yield"
    run_both(&mut sim, &mut plain);
    let yielded = run_both(&mut sim, &mut plain);
    let first = confined(110.0, None);
    assert!(first.1 > 1e-5, "{first:?}");
    check("yield (von Mises)", &yielded, 110.0, first);

    // the hand-over, point by point, as the switch will make it
    let elastic = Hencky::new(E, 0.0).unwrap();
    let held_model = ElasticStrain { elastic };
    let von_mises = VonMises::new(elastic, SIGMA_Y, H).unwrap();
    let mut query = sim.world.query::<(&Trial<2>, &PointHistory<VonMises>)>();
    let mut worst = 0.0f64;
    for (trial, history) in query.iter(&sim.world) {
        let stress = trial.0.kirchhoff;
        let carried = von_mises.hand_over(
            &history.committed,
            CarriedState::of_stress(Matrix3::identity(), stress),
        );
        let taken = held_model.take_over(&carried).unwrap();
        assert_eq!(taken.plastic_strain, history.committed.plastic_strain);
        let identity = SMatrix::<f64, 2, 2>::identity();
        let response = held_model
            .respond::<2>(&identity, &identity, &taken)
            .unwrap();
        worst = worst.max((response.kirchhoff - stress).amax());
    }
    println!(
        "the hand-over gives the stress back to {:.2e} σ_y",
        worst / SIGMA_Y
    );
    assert!(worst < 1e-10 * SIGMA_Y, "{worst:e}");

    // stage "held": the held model from the first step (λ = 0: no new load)
    let taken = run_both(&mut sim, &mut plain);
    let mut query = sim.world.query::<&PointHistory<ElasticStrain>>();
    assert_eq!(query.iter(&sim.world).count(), yielded.len(), "all held");
    let moved = taken
        .iter()
        .zip(&yielded)
        .map(|(a, b)| (a.0 - b.0).amax())
        .fold(0.0f64, f64::max);
    println!("held, first step: stress moved {:.2e} σ_y", moved / SIGMA_Y);
    assert!(moved < 1e-6 * SIGMA_Y, "{moved:e}");
    for (now, before) in taken.iter().zip(&yielded) {
        assert_eq!(now.1, before.1, "the plastic strain handed over");
    }
    run_both(&mut sim, &mut plain);
    let unloaded = run_both(&mut sim, &mut plain);
    let held_state = confined(70.0, Some(first.1));
    check("held (elastic_strain)", &unloaded, 70.0, held_state);
    let points_plastic = unloaded.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
    assert!(points_plastic > 0.0);

    // stage "back": von Mises again, from the hardened surface
    for _ in 0..2 {
        run_both(&mut sim, &mut plain);
    }
    let mut query = sim.world.query::<&PointHistory<VonMises>>();
    assert_eq!(query.iter(&sim.world).count(), yielded.len(), "all back");
    let reloaded = run_both(&mut sim, &mut plain);
    let last = confined(130.0, None);
    check("back (von Mises)", &reloaded, 130.0, last);
    println!(
        "the plastic strain without the hand-over would end at {:.6e} instead of {:.6e}",
        last.1 - first.1,
        last.1
    );
    assert!(last.1 > 1.5 * first.1);
}

/// The held model takes `b_e`, which Hencky does not hand over: a Hencky block switched to it
/// is refused at the stage's first step, the error naming the `material_of` line, the body,
/// the stage, the model and what is missing.
#[test]
fn a_switch_to_a_model_that_cannot_take_the_state_is_refused_with_its_line() {
    // the first two stages only: a switch back to hencky is refused when the scene is read
    let text: String = three_stages("elastic_strain")
        .replace(
            "model: \"von_mises\", sigma_y: 100.0, H: 10000.0, ",
            "model: \"hencky\", ",
        )
        .lines()
        .take(11)
        .map(|line| format!("{line}\n"))
        .collect();
    assert!(text.contains("\"hencky\""), "{text}");
    let mut sim = build("refused", &text);
    for _ in 0..2 {
        sim.step().unwrap();
    }
    let error = sim.step().expect_err("refused").to_string();
    println!("{error}");
    for part in [
        "material_of(...) at line 10 (body 'block', stage 'held')",
        "cannot take model 'elastic_strain'",
        "elastic left Cauchy–Green tensor b_e, which the old model does not hand over",
    ] {
        assert!(error.contains(part), "{part}: {error}");
    }
}

/// The trait's default `take_over` (here Hencky's): a carried plastic strain is refused (it
/// would be lost); without one the history is `history_from_stress`'s (Hencky refuses: its
/// stress is a function of `F` alone). The default `hand_over` gives `F` and the stress only.
#[test]
fn the_default_take_over_refuses_a_plastic_strain_it_would_lose() {
    let model = Hencky::new(E, 0.0).unwrap();
    let stress = Matrix3::from_diagonal(&nalgebra::Vector3::new(-10.0, -110.0, -10.0));
    let carried = CarriedState::of_stress(Matrix3::identity(), stress);
    assert_eq!(model.hand_over(&(), carried), carried);
    let with_strain = CarriedState {
        plastic_strain: Some(2.0e-5),
        ..carried
    };
    let error = model.take_over(&with_strain).unwrap_err();
    println!("{error}");
    assert!(
        error.contains("does not take an accumulated plastic strain") && error.contains("2.0"),
        "{error}"
    );
    let error = model.take_over(&carried).unwrap_err();
    println!("{error}");
    assert!(
        error.contains("cannot start from an initial stress"),
        "{error}"
    );
    // a von Mises point hands over its b_e and plastic strain, and takes them back
    let von_mises = VonMises::new(Hencky::new(E, 0.0).unwrap(), SIGMA_Y, H).unwrap();
    let history = von_mises.take_over(&with_strain).unwrap();
    assert_eq!(history.plastic_strain, 2.0e-5);
    let handed = von_mises.hand_over(&history, carried);
    assert_eq!(handed.plastic_strain, Some(2.0e-5));
    assert_eq!(
        handed.elastic_left_cauchy_green,
        Some(history.elastic_left_cauchy_green)
    );
}
