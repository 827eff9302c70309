//! Arc-length load control (Riks 1979, Crisfield 1981): the load factor λ becomes an unknown
//! of the Newton solve, so that a load-controlled problem (tractions, point loads, a body
//! force ramped with λ) is traced to and past a limit load, where λ must fall
//! (`solver(#{ control: "arc_length" })`; off by default, and then nothing here runs).
//!
//! # The step
//!
//! The loads the arc controls are proportional, f_ext(λ) = λ f̂ (f̂: the loads at λ = 1, which
//! the loads stage evaluates at the unit factor, [`unit_load`], [`take_reference_load`]). A load
//! step from the converged (u_n, λ_n) looks for the increment (Δu, Δλ) with
//!
//! ```text
//!   r(Δu, Δλ) = (λ_n + Δλ) f̂ − f_int(u_n + Δu) = 0,      ‖Δu‖² = Δl²    (cylindrical arc, Crisfield)
//! ```
//!
//! (‖·‖ over the free DOFs; no load term in the constraint). Each Newton iteration makes two
//! solves with the same tangent K,
//!
//! ```text
//!   K δu_r = r,     K δu_f = f̂,     δu = δu_r + δλ δu_f,
//! ```
//!
//! and δλ puts the new increment on the arc: with a = δu_f·δu_f, v = Δu + δu_r,
//!
//! ```text
//!   a δλ² + 2 (δu_f·v) δλ + (v·v − Δl²) = 0.
//! ```
//!
//! * The predictor (Δu = 0): the two roots have opposite signs; the sign is that of
//!   Δu_{n−1}·δu_f (Feng, Perić & Owen 1996: the step keeps going the way the previous one went,
//!   which turns λ down past a limit point where K has a negative eigenvalue and δu_f flips),
//!   the first step's that of its load increment. (At Δu = 0 a plastic point's trial state is
//!   elastic, so K there is the elastic tangent: past a plastic limit the predictor points up
//!   in λ and the correctors bring it down. A secant predictor, the previous increment scaled
//!   to the arc, was tried on the footing below and did worse: points inverted under F-bar.)
//! * A corrector takes the root whose new increment makes the smaller angle with the old one,
//!   the larger (Δu + δu)·Δu (Crisfield 1981).
//! * Where the quadratic has no real root (a large residual against a short arc, typical of
//!   plastic steps), δλ comes from the linearised constraint instead, the iterative change
//!   orthogonal to the step's increment so far (Ramm 1981, the updated normal plane), which is
//!   always solvable while Δu·δu_f ≠ 0:
//!
//!   ```text
//!     Δu·(δu_r + δλ δu_f) = 0   ⇒   δλ = −(Δu·δu_r) / (Δu·δu_f).
//!   ```
//!
//!   The converged point then lies a little outside the arc (each such iteration lengthens
//!   Δu); the run counts these iterations ([`ArcLength::linearised`]).
//!
//! The step converges by the usual criterion on r at the current λ (the predictor is always
//! taken: the residual at Δu = 0 is the previous step's converged one, and in MPM also the
//! out-of-balance force of the grid reset, which a large step makes large). A converged
//! increment that goes back along the path, Δu·Δu_{n−1} < 0, or unloads, Δλ < 0 with
//! f̂·Δu < 0, is refused and the arc cut ([`keep_going_forward`]): past a plastic limit Newton
//! can land on the elastic unloading branch, which is on the arc and in equilibrium but is the
//! path already traced. (So a genuine snap-back is not followed either.) Both tests are on the
//! cosines, relative to the lengths ([`turns_back`]): a dot product counts as negative below
//! −[`TURN_BACK_COSINE`] |a| |b|. Δu is a sum of Newton corrections, each with round-off of
//! about ε times its own size, so once cuts have shrunk the arc far below the corrections a
//! step makes, Δu·f̂ of order −1e-15 is noise, not a turn-back (the 8-cell footing was cut on
//! such values); a real turn-back onto the unloading branch has a cosine of order 0.1 to 1.
//!
//! # Held loads
//!
//! A scene may hold loads beside the controlled ones (`held: true`: the weight that balances a
//! geostatic initial stress while a footing is pushed). Every load is affine in the load factor,
//! so the external force splits into a held part and the controlled one,
//!
//! ```text
//!   f_ext(λ) = f_fixed + λ f̂,     f_fixed = f(λ = 0),     f̂ = f(1) − f(0),
//! ```
//!
//! and the arc, the predictor's δu_f = K⁻¹ f̂, the turn-back tests and λ act on f̂ only: the
//! residual above becomes f_fixed + (λ_n + Δλ) f̂ − f_int. The loads are evaluated twice per
//! step ([`split_fixed_loads`]): at λ = 1 in `Hook::Loads` as without held loads, then at λ = 0
//! by running the load modules' systems again ([`FixedLoadsSchedule`]; a load module adds its
//! system to both with `effects::arc_length::add_load_system`). A scene without held loads
//! evaluates them once and computes f_ext = λ f̂ as before, bit for bit. The first step first
//! puts the body in equilibrium under f_fixed at λ = 0 (a rebalancing at a fixed load factor,
//! below, whatever `rebalance` says for the later steps): held loads balanced by an initial
//! stress take no iteration there, held loads on a stress-free body are applied in full, as
//! load control's first step applies them, and the arc's first step starts from that
//! equilibrium (its start residual is the held loads', not a cell crossing: not warned).
//! A follower pressure is not held (`effects::pressure` keeps its own f̂ part up to date).
//!
//! The later steps rebalance too by default (`rebalance: "auto"`, [`Rebalance::resolve`]:
//! fixed with held loads, off without). A held load does not scale with λ, so the
//! out-of-balance force it leaves on a step's new grid does not either, and against the short
//! arcs of a small controlled load it can be the larger part of the step: an elastic block on
//! GIMP with its weight held (`tests/arc_length_held.rs`) reaches new nodes with slivers of
//! support at step 2 (22 DOFs, then 31), where |K⁻¹ r| at the predictor is 4.4e-2 against
//! Δl = 3.2e-4. Left in the arc (`rebalance: "off"`), that correction is step 2's increment
//! (the quadratic has no real root; the normal-plane predictor), so Δu_2 is the sliver nodes'
//! settling, not the path, and Δu_2·δu_f = −4.5e-5 < 0 turns step 3's predictor down: λ falls,
//! the step is refused as a turn-back until the cuts run out. Rebalanced first, the correction
//! is not part of the path (`accept` keeps the arc's part) and the block runs.
//!
//! # Stages
//!
//! In a staged scene the last stage may be arc-controlled (`stage(#{ .., control:
//! "arc_length" })`, `scene::stages`): its steps, from [`ArcLengthSpec::first_step`] on, are
//! the arc's, the earlier stages' are load-controlled and no system of the arc runs in them
//! ([`arc_controls_step`]). In the arc's stage k every load is affine in the stage's own λ (the
//! earlier stages' loads held at their final value, the stage's own following λ), so the split
//! above is exact with the loads evaluated at the stage's λ = 0 and 1: f_fixed holds the earlier
//! stages' loads (and the stage's `held` ones), f̂ the stage's own. The scene always has held
//! loads then (`fixed_loads`), so the arc's first step first balances f_fixed at λ = 0 from
//! the last load-controlled state, and its first arc is sized by the stage's first load factor.
//! A release ramped over the arc's stage, (1 − λ) f_end, is refused when the scene is read
//! (λ goes past 1 under the arc).
//!
//! # A plateau
//!
//! A perfectly plastic body reaches its limit load on a plateau: λ stays flat while u grows.
//! There the arc's predictor is elastic (module docs above) and Newton lands on the elastic
//! unloading branch about the plateau, which is refused; the cuts shrink the arc to nothing
//! and the step fails. [`keep_going_forward`] then says what happened: when the last
//! converged step was at the largest λ and the current stiffness parameter (Bergan et al.
//! 1978), the last step's Δλ/‖Δu‖ over the first's ([`ArcLength::stiffness_parameter`]), is
//! below [`PLATEAU_STIFFNESS`] in size ([`ArcLength::on_plateau`]), the error states that
//! the limit load was reached and gives λ_max, instead of calling it a turn-back. (The run
//! still stops with that error: the plateau is not followed. The two numbers are not in a
//! checkpoint: after a resume the error is the turn-back one until two steps converged.)
//!
//! # A step that starts out of balance
//!
//! At Δu = 0 the residual is λ_n f̂ − f_int(u_n) on the new grid: the previous step's converged
//! state seen by the reset grid, so it is exactly the out-of-balance force the step inherits.
//! [`record_start_imbalance`] keeps
//!
//! ```text
//!   initial_imbalance = ‖λ_n f̂ − f_int(u_n)‖_free / ‖λ_n f̂‖     (summary.json, per step)
//! ```
//!
//! and warns once when it exceeds [`START_IMBALANCE`] = 0.1: measured on the 8-cell footing
//! (`scripts/footing_pressure_arc.rhai`), 0.017 to 0.061 on the steps before its peak and 0.72,
//! 0.64, 0.41 at the three steps after points crossed cell faces (linear MPM's gradients jump
//! there), where the arc collapses; on the thick cylinder at most 0.045. Such a step does not
//! start from equilibrium; near a limit load its answer may depend on the resolution. (Under
//! load control the first residual holds the step's load increment too, so this measure is
//! the arc's only.)
//!
//! # Rebalancing before the arc
//!
//! With `solver(#{ control: "arc_length", rebalance: "fixed" })` (or `"free"`; `"auto"`, the
//! default, is `"fixed"` in a scene with held loads, "Held loads" above) a step first
//! removes the residual it starts with, then takes its arc from there. The rebalancing is
//! Newton without the arc constraint, from the committed state on the step's grid (Δu = 0),
//! inside the same Newton loop and with the same criterion and tolerance:
//!
//! ```text
//!   fixed:  λ = λ_n,  K δu = r                                      (no load increment)
//!   free:   δu = δu_r + δλ δu_f,  δλ = −(δu_f·δu_r)/(δu_f·δu_f)      (the shortest correction:
//!                                                                    normal flow, λ moves as
//!                                                                    little as the equilibrium needs)
//! ```
//!
//! Its converged state (u_c = u_n + Δu_c, λ_c; λ_c = λ_n when fixed) is the step's start for
//! the arc ([`finish_rebalance`]): the arc's increment is measured from it,
//!
//! ```text
//!   r = (λ_c + Δλ) f̂ − f_int(u_n + Δu_c + Δu_a) = 0,     ‖Δu_a‖² = Δl²,
//! ```
//!
//! the predictor is the one above at Δu_a = 0, and the step is accepted at
//! Δu = Δu_c + Δu_a, λ_c + Δλ. The correction moves along no path (it only puts the committed
//! state back into equilibrium on the new grid, a resolution effect), so the path direction
//! that the next predictor's sign and the turn-back tests compare with is Δu_a, the arc's part:
//! `accept` keeps Δu_a as Δu_{n−1}, the tests compare Δu_a with it, and the unloading test takes
//! Δλ = λ − λ_c. Two refusals: a free rebalancing that unloads (λ_c < λ_n with f̂·Δu_c < 0) by more
//! than the last step went (‖Δu_c‖ > ‖Δu_{n−1}‖: the nearest equilibrium is back on the path
//! already traced), and one that does not converge (at λ_n
//! there may be no equilibrium near the committed state past a limit, where the new grid
//! carries less than λ_n). Either fails the attempt, recoverably: the arc is cut, and since the
//! rebalancing would repeat exactly (it starts from the committed state and ignores the arc),
//! the step's next attempts go without it, from the committed state as without the option,
//! and the run warns once. A cut after a converged rebalancing restarts from the committed
//! state too (the grid is reset) and rebalances again. The arc is sized by its own iterations
//! (the step's minus the rebalancing's), each step records `rebalance_iterations`,
//! `rebalanced_imbalance` (as `initial_imbalance`, at u_c) and `rebalanced_load_factor` (λ_c),
//! and `initial_imbalance` stays the residual the step inherited.
//!
//! # Over several processes
//!
//! Under `mpirun -n N` with replicated state (`effects::distributed`) every process holds
//! every point and the whole grid: f̂ (and f_fixed) are formed in full on every process, a
//! follower pressure's f̂ follows the iterate on every process, `f_int` is summed before the
//! residual is formed and every solve's correction is gathered to every process. So Δu, δu_r,
//! δu_f, Δu_{n−1} and f̂ are whole and the same bits on every process, and so are every dot
//! product above, the roots, the turn-back and rebalancing decisions, the step policy's end
//! tests and its cuts: nothing here talks to the other processes. The second solve, K δu_f = f̂,
//! calls the same distributed solver as the first, on every process (every process reaches
//! [`correct_load_factor`] in the same iteration with the same state): it sets the shares of K
//! again (`MatZeroEntries`, then each process adds its share) and solves the right-hand side
//! every process passes alike. `tests/mpi.rs` runs the thick cylinder past its peak over 2 and
//! 3 processes and compares it with the serial run.
//!
//! # With decomposed points
//!
//! Under `--decompose` each process holds its own points and the grid nodes they touch: its
//! DOFs are its owned and ghost nodes' (a ghost holding its owner's values: the force sums at
//! the shared nodes, the correction brought back to the local rows), `Newton::shared_grid` says
//! which nodes it owns. What the arc needs is then:
//!
//! * f̂ at λ = 1: the loads stage's `f_ext`, already the processes' sum at the shared nodes
//!   (`effects::distributed::decomposition::sum_external_force`, before `Hook::BeforeSolve`);
//!   with held loads their second evaluation at λ = 0 is summed the same way
//!   ([`SumFixedLoadsSchedule`], run by [`split_fixed_loads`]); whether f̂ loads a free DOF is
//!   asked of every process ([`take_reference_load`]).
//! * Every dot product and norm (δu_f·δu_f, δu_f·(Δu + δu_r), (Δu + δu_r)², Δu·Δu,
//!   Δu·δu_f, Δu·δu_r, the roots' Δu·(v + δλ δu_f), Δu_{n−1}·δu_f, ‖δu_r‖ for `"auto"`, the
//!   shortest correction's, the turn-back tests' Δu·Δu_{n−1}, f̂·Δu, ‖Δu‖, ‖f̂‖, the
//!   rebalancing's f̂·Δu_c, ‖Δu_c‖, and `initial_imbalance`'s ‖r‖, ‖f_ext‖): each DOF or node
//!   counted on its owner only, the processes' parts added in rank order (`SharedGrid::sum`,
//!   collective: the same bits on every process); [`load_correction_with`] takes that inner
//!   product. Serially the sums are the same as before, in the same order, bit for bit.
//! * Δu_{n−1}: the next step's nodes, owners and DOFs are not this step's (points change
//!   process), so [`ArcLength::accept`] keeps it whole on every process, each node's value
//!   from its owner (a sum over the processes of a whole-grid vector, once per step); its
//!   norm is then a local sum, the same on every process.
//! * The second solve `K δu_f = f̂`: the decomposed solver, with each process's local f̂ (its
//!   owned rows are right), the solution back at its local rows.
//!
//! So every decision (the roots, the predictor's sign, the turn-back and rebalancing
//! refusals, the cuts, `max_load_factor`, the end at λ back to zero, a plateau) is taken from
//! the same numbers on every process. `tests/mpi.rs` runs a traction-loaded footing and a
//! column with its weight held whose points change process, over 2 and 3 processes, against
//! the serial run.
//!
//! # Step control
//!
//! [`ArcLengthControl`] is the policy (pure): the first arc is sized so that the first step's
//! predictor raises λ by the scene's first load factor, Δl₀ = |λ₁| ‖δu_f‖; after a converged
//! step the arc is scaled by √(target iterations / iterations) within [1/2, 2] (Crisfield); a
//! failed attempt is repeated with half the arc, at most `max_step_cuts` times. The run ends at
//! `max_load_factor`, when λ has fallen back to zero after a peak (the load is shed: collapse
//! traced), or after the scene's number of load steps; the peak λ and whether the run went
//! past it are recorded ([`ArcLengthControl::report`]).

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::node_storage::NodeVec;
use crate::resources::{
    GridFields, LoadStep, Newton, NewtonSettings, RunStatus, SharedGrid, SolverError, Warnings,
};
use crate::solver::NO_DOF;

/// The scene's arc-length options (a part of the scene: `solver(#{ control: "arc_length" })`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArcLengthSpec {
    /// Newton iterations per step the arc is scaled towards.
    pub target_iterations: usize,
    /// The run ends when λ reaches this (infinite: no such end).
    pub max_load_factor: f64,
    /// Whether (and how) a step first removes the out-of-balance force it starts with
    /// (module docs, "Rebalancing before the arc").
    pub rebalance: Rebalance,
    /// Whether the scene has held loads: f_ext = f_fixed + λ f̂, the loads evaluated twice per
    /// step (module docs, "Held loads"); always in a staged scene whose arc starts after the
    /// first stage (the earlier stages' loads are held).
    pub fixed_loads: bool,
    /// The first load step the arc controls (1-based): 1, or the first step of the
    /// arc-controlled stage of a staged scene (module docs, "Stages"); the steps before it are
    /// load-controlled and nothing of the arc runs in them.
    pub first_step: usize,
}

impl Default for ArcLengthSpec {
    fn default() -> Self {
        Self {
            target_iterations: 5,
            max_load_factor: f64::INFINITY,
            rebalance: Rebalance::Off,
            fixed_loads: false,
            first_step: 1,
        }
    }
}

impl ArcLengthSpec {
    /// The load factor that sizes the first arc: the first factor of the arc's steps.
    pub fn first_factor(&self, load_factors: &[f64]) -> f64 {
        load_factors
            .get(self.first_step.saturating_sub(1))
            .copied()
            .unwrap_or(0.0)
    }
}

/// The equilibrium correction before a step's arc (module docs, "Rebalancing before the arc";
/// `solver(#{ rebalance: "fixed" })`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Rebalance {
    /// None: the arc starts from the committed state as the new grid sees it.
    #[default]
    Off,
    /// Newton at λ = λ_n, no arc constraint: `K δu = r`.
    Fixed,
    /// Newton with λ free and no arc constraint, each correction the shortest (normal flow):
    /// `δu = δu_r + δλ δu_f`, `δλ = −(δu_f·δu_r)/(δu_f·δu_f)`.
    Free,
    /// As [`Rebalance::Fixed`], but only on a step whose start correction is at least its arc,
    /// ‖δu_r‖ ≥ Δl at the predictor (the arc cannot absorb it: module docs, "Held loads"); the
    /// default of a scene with held loads ([`Rebalance::resolve`]).
    Auto,
}

impl Rebalance {
    /// The scene's words, in the order of the variants.
    pub const WORDS: [&'static str; 4] = ["off", "fixed", "free", "auto"];

    /// The variant of a scene word.
    pub fn from_word(word: &str) -> Option<Self> {
        match word {
            "off" => Some(Self::Off),
            "fixed" => Some(Self::Fixed),
            "free" => Some(Self::Free),
            "auto" => Some(Self::Auto),
            _ => None,
        }
    }

    /// The scene word.
    pub fn word(self) -> &'static str {
        Self::WORDS[self as usize]
    }

    /// The rebalancing of a scene's word or none (the default, `"auto"`): [`Rebalance::Auto`]
    /// with held loads (`held_loads`, [`ArcLengthSpec::fixed_loads`]), [`Rebalance::Off`]
    /// without them (module docs, "Held loads": a held load's imbalance on a step's new grid
    /// does not scale with λ; without held loads the runs stay as they were, bit for bit).
    /// `None` for a word that is none of these.
    pub fn resolve(word: Option<&str>, held_loads: bool) -> Option<Self> {
        match word.map_or(Some(Self::Auto), Self::from_word)? {
            Self::Auto if !held_loads => Some(Self::Off),
            mode => Some(mode),
        }
    }
}

/// What a step's rebalancing did ([`finish_rebalance`]; the step's measures
/// `rebalance_iterations`, `rebalanced_imbalance`, `rebalanced_load_factor`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rebalanced {
    /// Newton iterations (linear solves) it took.
    pub iterations: usize,
    /// ‖λ_c f̂ − f_int(u_c)‖_free / ‖λ_c f̂‖ at its converged state (as `initial_imbalance`).
    pub imbalance: Option<f64>,
    /// λ_c: the load factor it converged at (λ_n when fixed).
    pub factor: f64,
}

/// How δλ of an iteration was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Root {
    /// A root of the arc's quadratic.
    Arc,
    /// The linearised constraint (the quadratic had no real root).
    Linearised,
}

fn dot(u: &[f64], v: &[f64]) -> f64 {
    u.iter().zip(v).map(|(a, b)| a * b).sum()
}

/// The arc's sums over the whole problem (module docs, "With decomposed points"): serially
/// and with replicated state the plain sums, in DOF (node) order as before; on a grid split
/// among processes (`Newton::shared_grid`) each DOF and node counted on its node's owner only
/// (a ghost holds its owner's values) and the processes' parts added
/// ([`SharedGrid::sum`]: collective, the same bits on every process, so every process takes
/// the arc's decisions alike).
struct OverProcesses<'a> {
    shared: Option<&'a dyn SharedGrid>,
    /// By DOF: whether this process counts it (empty without `shared`).
    counted: Vec<bool>,
}

impl<'a> OverProcesses<'a> {
    fn new<const D: usize>(fields: &GridFields<D>, shared: Option<&'a dyn SharedGrid>) -> Self {
        let mut counted = Vec::new();
        if let Some(shared) = shared {
            counted.resize(fields.dof_count, false);
            for (node, dofs) in fields.dofs.written() {
                for &dof in dofs.iter().filter(|&&d| d != NO_DOF) {
                    counted[dof as usize] = shared.owned(node);
                }
            }
        }
        Self { shared, counted }
    }

    /// Whether this process counts `node` (its owner, or the only process).
    fn counts(&self, node: usize) -> bool {
        self.shared.is_none_or(|s| s.owned(node))
    }

    /// This process's parts summed over the processes (collective; as they are serially).
    fn sum<const N: usize>(&self, parts: [f64; N]) -> Result<[f64; N], String> {
        let Some(shared) = self.shared else {
            return Ok(parts);
        };
        let sums = shared.sum(&parts)?;
        <[f64; N]>::try_from(sums)
            .map_err(|s| format!("{} sums of {N} values over the processes", s.len()))
    }

    /// u·v of two vectors by DOF, over the whole problem's free DOFs.
    fn dot(&self, u: &[f64], v: &[f64]) -> Result<f64, String> {
        if self.shared.is_none() {
            return Ok(dot(u, v));
        }
        let part = (u.iter().zip(v).zip(&self.counted))
            .filter(|(_, counted)| **counted)
            .map(|((a, b), _)| a * b)
            .sum();
        Ok(self.sum([part])?[0])
    }

    /// This process's part of Σ_i u_i · v_i over the nodes it counts (to be [`Self::sum`]med).
    fn node_dot<const D: usize>(&self, u: &[SVector<f64, D>], v: &[SVector<f64, D>]) -> f64 {
        (u.iter().zip(v).enumerate())
            .filter(|(node, _)| self.counts(*node))
            .map(|(_, (a, b))| a.dot(b))
            .sum()
    }
}

/// A failure to sum the arc's figures over the processes (a message not received): the run's.
fn sum_failed(step: usize, why: String) -> SolverError {
    SolverError::Module {
        step,
        what: format!("arc-length control: summing over the processes: {why}"),
        recoverable: false,
    }
}

/// |u|: the square root of Σ_i |u_i|² over every node (a vector whole on every process).
fn length<const D: usize>(u: &[SVector<f64, D>]) -> f64 {
    u.iter().map(|v| v.norm_squared()).sum::<f64>().sqrt()
}

/// δλ of one iteration (see the module docs): `increment` Δu before it, `residual_part` δu_r,
/// `load_part` δu_f, `radius` Δl; `sign` (±1) the predictor's direction, used when Δu = 0.
/// `None` when no δλ exists (the linearised constraint is singular, Δu·δu_f = 0, or a value
/// is not finite).
pub fn load_correction(
    increment: &[f64],
    residual_part: &[f64],
    load_part: &[f64],
    radius: f64,
    sign: f64,
) -> Option<(f64, Root)> {
    let dot = |u: &[f64], v: &[f64]| Ok(dot(u, v));
    load_correction_with(&dot, increment, residual_part, load_part, radius, sign).unwrap_or(None)
}

/// An inner product of two vectors by DOF over the whole problem's free DOFs (on a grid split
/// among processes a collective sum: module docs, "With decomposed points"); its error is a
/// failed sum.
pub type InnerProduct<'a> = dyn Fn(&[f64], &[f64]) -> Result<f64, String> + 'a;

/// [`load_correction`] with the inner product `dot` (over the whole problem's free DOFs: on
/// a grid split among processes a collective sum, which every process calls alike; module
/// docs, "With decomposed points"); its error is `dot`'s.
pub fn load_correction_with(
    dot: &InnerProduct<'_>,
    increment: &[f64],
    residual_part: &[f64],
    load_part: &[f64],
    radius: f64,
    sign: f64,
) -> Result<Option<(f64, Root)>, String> {
    let v: Vec<f64> = increment
        .iter()
        .zip(residual_part)
        .map(|(a, b)| a + b)
        .collect();
    let a = dot(load_part, load_part)?;
    let b = 2.0 * dot(load_part, &v)?;
    let c = dot(&v, &v)? - radius * radius;
    let discriminant = b * b - 4.0 * a * c;
    let predictor = dot(increment, increment)? == 0.0;
    let finite = |x: f64| x.is_finite().then_some(x);
    if a > 0.0 && discriminant >= 0.0 {
        // the roots without cancellation (Numerical Recipes §5.6)
        let q = -0.5 * (b + b.signum() * discriminant.sqrt());
        let (r1, r2) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
        let chosen = if predictor {
            if sign * r1 >= sign * r2 { r1 } else { r2 }
        } else {
            // (Δu + δu)·Δu for a root: Δu·(v + root δu_f)
            let cosine = |root: f64| {
                let moved: Vec<f64> = (v.iter().zip(load_part))
                    .map(|(vi, f)| vi + root * f)
                    .collect();
                dot(increment, &moved)
            };
            if cosine(r1)? >= cosine(r2)? { r1 } else { r2 }
        };
        return Ok(finite(chosen).map(|root| (root, Root::Arc)));
    }
    if predictor {
        // ‖δu_r‖ > Δl with no real root: the normal-plane predictor
        return Ok(finite(sign * radius / a.sqrt()).map(|root| (root, Root::Linearised)));
    }
    let denominator = dot(increment, load_part)?;
    if denominator == 0.0 {
        return Ok(None);
    }
    let numerator = dot(increment, residual_part)?;
    Ok(finite(-numerator / denominator).map(|root| (root, Root::Linearised)))
}

/// The state of the arc-length step being solved (inserted only when the scene asks for
/// arc-length control), in node order where it outlives the step's DOF numbering.
#[derive(Resource, Debug)]
pub struct ArcLength<const D: usize> {
    /// f̂: the external force at λ = 1, by node (without the held loads).
    reference: Vec<SVector<f64, D>>,
    /// f_fixed: the held loads, by node (empty in a scene without them: f_ext = λ f̂).
    fixed: Vec<SVector<f64, D>>,
    /// Whether the scene has held loads ([`split_fixed_loads`] runs; the first step starts
    /// with a rebalancing at λ = 0).
    pub fixed_loads: bool,
    /// f̂ at the free DOFs.
    reference_dofs: Vec<f64>,
    /// λ at the start of the step (set by the driver).
    pub start: f64,
    /// λ of the current iterate.
    pub factor: f64,
    /// Δl of the step; 0: sized from `first_increment` by the first predictor.
    pub radius: f64,
    /// The first step's load increment (sizes the first arc).
    pub first_increment: f64,
    /// Δu of the previous converged step, by node (empty before the first).
    previous: Vec<SVector<f64, D>>,
    /// Δu of the current iterate, by node.
    current: Vec<SVector<f64, D>>,
    /// `Newton::iterations` at the last correction.
    corrected: usize,
    /// Iterations of the current attempt whose δλ came from the linearised constraint.
    pub linearised: usize,
    /// ‖r‖ / ‖λ_n f̂‖ at the current step's start ([`record_start_imbalance`]).
    pub start_imbalance: Option<f64>,
    /// Whether a step's start imbalance was warned about (once per run).
    warned_imbalance: bool,
    /// The scene's rebalancing.
    pub rebalance: Rebalance,
    /// Whether the current attempt is still removing its start residual (before the arc).
    rebalancing: bool,
    /// Δu_c, by node: the increment at which the rebalancing converged, the arc's origin
    /// (empty: none, the arc starts at Δu = 0).
    origin: Vec<SVector<f64, D>>,
    /// The current attempt's rebalancing, once converged.
    pub rebalanced: Option<Rebalanced>,
    /// The step whose attempt began a rebalancing that has not converged: while it is the
    /// current step, that attempt failed during it, and the step's next attempts go without.
    rebalancing_step: Option<usize>,
    /// Whether a step that went without its rebalancing was warned about (once per run).
    warned_unbalanced: bool,
    /// The first load step the arc controls ([`ArcLengthSpec::first_step`]).
    pub first_step: usize,
    /// Δλ / ‖Δu‖ of the arc's part of the first and of the last converged step: their ratio
    /// is the current stiffness parameter ([`ArcLength::stiffness_parameter`]).
    first_slope: Option<f64>,
    last_slope: f64,
    /// The largest λ of a converged step.
    peak: f64,
}

impl<const D: usize> ArcLength<D> {
    pub fn new(first_increment: f64) -> Self {
        Self {
            reference: Vec::new(),
            fixed: Vec::new(),
            fixed_loads: false,
            reference_dofs: Vec::new(),
            start: 0.0,
            factor: 0.0,
            radius: 0.0,
            first_increment,
            previous: Vec::new(),
            current: Vec::new(),
            corrected: 0,
            linearised: 0,
            start_imbalance: None,
            warned_imbalance: false,
            rebalance: Rebalance::Off,
            rebalancing: false,
            origin: Vec::new(),
            rebalanced: None,
            rebalancing_step: None,
            warned_unbalanced: false,
            first_step: 1,
            first_slope: None,
            last_slope: f64::NAN,
            peak: f64::NEG_INFINITY,
        }
    }

    /// Whether the arc controls load step `step` (the steps before [`ArcLength::first_step`]
    /// are load-controlled: a staged scene's earlier stages).
    pub fn controls(&self, step: usize) -> bool {
        step >= self.first_step
    }

    /// Prepares an attempt from λ = `start` with the arc `radius` (0: sized by the predictor).
    pub fn begin_attempt(&mut self, start: f64, radius: f64) {
        self.start = start;
        self.factor = start;
        self.radius = radius;
        self.corrected = 0;
        self.linearised = 0;
        self.current.clear();
        self.rebalancing = matches!(self.rebalance, Rebalance::Fixed | Rebalance::Free)
            || self.balances_held_loads();
        self.origin.clear();
        self.rebalanced = None;
    }

    /// Whether the current attempt of load step `step` may begin a rebalancing, which it then
    /// begins: not when an earlier attempt of the step failed while rebalancing, since this one
    /// would repeat it exactly (it starts from the committed state and ignores the arc); the
    /// attempt then starts from the committed state, out of balance, warned once per run.
    fn may_rebalance(&mut self, step: usize, warnings: &mut Warnings) -> bool {
        if self.rebalancing_step != Some(step) {
            self.rebalancing_step = Some(step);
            return true;
        }
        if !self.warned_unbalanced {
            self.warned_unbalanced = true;
            warnings.0.push(format!(
                "step {step}: the rebalancing before the arc (rebalance: \"{}\") failed (the \
                 step's failed attempts in summary.json say why); the step's next attempts \
                 start from the committed state, out of balance, as without rebalancing \
                 (warned once per run; summary.json steps without rebalance_iterations)",
                self.rebalancing_mode().word()
            ));
        }
        false
    }

    /// Whether the current attempt is still removing its start residual.
    pub fn rebalancing(&self) -> bool {
        self.rebalancing
    }

    /// Whether this attempt is the first step's with held loads, which first puts the body in
    /// equilibrium under them at λ = 0 (module docs, "Held loads").
    fn balances_held_loads(&self) -> bool {
        self.fixed_loads && self.previous.is_empty() && self.start == 0.0
    }

    /// How the current attempt rebalances: at a fixed λ when it balances the held loads (the
    /// first step's, whatever the scene chose for the later steps: with λ free the balance
    /// of the held loads alone would move the controlled ones too), else the scene's choice.
    fn rebalancing_mode(&self) -> Rebalance {
        if self.balances_held_loads() {
            return Rebalance::Fixed;
        }
        match self.rebalance {
            Rebalance::Off | Rebalance::Auto => Rebalance::Fixed,
            mode => mode,
        }
    }

    /// f_ext at load factor `factor`: f_fixed + λ f̂ (λ f̂ without held loads).
    /// Only the nodes where f_fixed or f̂ is not zero are written (the others are zero: the
    /// grid's pages there stay unallocated, `node_storage`).
    fn set_external(&self, external: &mut NodeVec<SVector<f64, D>>, factor: f64) {
        external.reset();
        let zero = SVector::<f64, D>::zeros();
        if self.fixed.is_empty() {
            for (node, reference) in self.reference.iter().enumerate() {
                if *reference != zero {
                    external[node] = reference * factor;
                }
            }
        } else {
            for (node, (reference, fixed)) in self.reference.iter().zip(&self.fixed).enumerate() {
                if *reference != zero || *fixed != zero {
                    external[node] = fixed + reference * factor;
                }
            }
        }
    }

    /// A follower load's held force changed by `change` (by node) with the iterate: f_fixed is
    /// the loads at λ = 0 in the current configuration, so it follows (`effects::pressure`: a
    /// pressure of an earlier stage under the arc of a later one).
    pub fn change_fixed(&mut self, change: &NodeVec<SVector<f64, D>>) {
        if self.fixed.is_empty() {
            self.fixed = vec![SVector::zeros(); change.len()];
        }
        for (node, df) in change.written() {
            self.fixed[node] += df;
        }
    }

    /// A follower load's force at λ = 1 changed by `change` (by node) with the iterate: f̂ is
    /// the loads at λ = 1 in the current configuration, so it and its free-DOF part follow
    /// (`effects::pressure`).
    pub fn change_reference(
        &mut self,
        change: &NodeVec<SVector<f64, D>>,
        dofs: &NodeVec<[u32; D]>,
    ) {
        for (node, df) in change.written() {
            self.reference[node] += df;
            for (c, &dof) in dofs[node].iter().enumerate() {
                if dof != NO_DOF {
                    self.reference_dofs[dof as usize] += df[c];
                }
            }
        }
    }

    /// The attempt converged: its increment gives the next predictor its direction (the arc's
    /// part Δu − Δu_c after a rebalancing). On a grid split among processes (`shared`:
    /// `Newton::shared_grid`) Δu_{n−1} is kept whole on every process, each node's value from
    /// its owner (collective: the next step's owners and DOFs are not this one's; module
    /// docs, "With decomposed points").
    pub fn accept(&mut self, shared: Option<&dyn SharedGrid>) -> Result<(), String> {
        match shared {
            None => self.previous.clone_from(&self.current),
            Some(shared) => {
                let mut values = Vec::with_capacity(self.current.len() * D);
                for (node, u) in self.current.iter().enumerate() {
                    if shared.owned(node) {
                        values.extend(u.iter());
                    } else {
                        values.extend([0.0; D]);
                    }
                }
                let whole = shared.sum(&values)?;
                self.previous = whole
                    .chunks_exact(D)
                    .map(SVector::<f64, D>::from_column_slice)
                    .collect();
            }
        }
        let slope = (self.factor - self.start) / self.increment_norm();
        if slope.is_finite() {
            self.last_slope = slope;
            self.first_slope.get_or_insert(slope);
        }
        self.peak = self.peak.max(self.factor);
        Ok(())
    }

    /// The current stiffness parameter (Bergan et al. 1978): the last converged step's
    /// Δλ / ‖Δu‖ over the first's (1 on a linear path, 0 at a limit load, negative past it);
    /// `None` before two steps (or after a resume: it is not saved).
    pub fn stiffness_parameter(&self) -> Option<f64> {
        self.first_slope
            .map(|first| self.last_slope / first)
            .filter(|s| s.is_finite())
    }

    /// Whether the last converged step was on a plateau at the largest load factor: λ_n at
    /// the peak and the current stiffness parameter below [`PLATEAU_STIFFNESS`] in size (the
    /// load no longer changes while the displacement grows: the limit load is reached).
    pub fn on_plateau(&self) -> bool {
        self.peak - self.start <= 1e-6 * self.peak.abs()
            && self
                .stiffness_parameter()
                .is_some_and(|s| s.abs() < PLATEAU_STIFFNESS)
    }

    /// ‖Δu − Δu_c‖ of the last accepted step, Δu_{n−1} (over the free DOFs it was taken on;
    /// Δu_c = 0 without rebalancing; whole on every process): Δl on a converged step whose
    /// iterations all stayed on the arc (`linearised` = 0).
    pub fn increment_norm(&self) -> f64 {
        length(&self.previous)
    }
}

/// The run condition of every system of the arc: the step is one the arc controls
/// ([`ArcLength::controls`]; in a staged scene the earlier stages' steps are load-controlled).
pub fn arc_controls_step<const D: usize>(arc: Res<ArcLength<D>>, step: Res<LoadStep>) -> bool {
    arc.controls(step.number)
}

/// `Hook::AfterDofs` (so before `Hook::Loads`): the loads are evaluated at λ = 1
/// (f̂).
pub fn unit_load(mut step: ResMut<LoadStep>) {
    step.factor = 1.0;
}

/// The loads' second evaluation in a scene with held loads (module docs, "Held loads"): the
/// load modules add their `Hook::Loads` systems to it too, run by [`split_fixed_loads`] at
/// λ = 0.
#[derive(bevy_ecs::schedule::ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct FixedLoadsSchedule;

/// The place of the n-th system added to [`FixedLoadsSchedule`] (they run in the order added,
/// as in their hook).
#[derive(bevy_ecs::schedule::SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FixedLoadSlot(pub usize);

/// Run by [`split_fixed_loads`] after [`FixedLoadsSchedule`]: a distributed run with decomposed
/// points adds the processes' shares of f(0) at the shared nodes there, as it does after the
/// loads stage for f(1) (`effects::distributed`; absent otherwise).
#[derive(bevy_ecs::schedule::ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct SumFixedLoadsSchedule;

/// How many systems [`FixedLoadsSchedule`] holds.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct FixedLoadSlots(pub usize);

/// `Hook::BeforeSolve`, before [`take_reference_load`] (scheduled only in a scene with held
/// loads): the loads were evaluated at λ = 1, f(1) = f_fixed + f̂; evaluated again at λ = 0
/// ([`FixedLoadsSchedule`]) they give f_fixed, and f̂ = f(1) − f(0) is left as the external
/// force for [`take_reference_load`]. Every load is affine in λ, so f(λ) = f_fixed + λ f̂.
pub fn split_fixed_loads<const D: usize>(world: &mut World) {
    if world.resource::<RunStatus>().0.is_some() {
        return;
    }
    let unit = {
        let mut fields = world.resource_mut::<GridFields<D>>();
        let nodes = fields.external_force.len();
        std::mem::replace(
            &mut fields.external_force,
            NodeVec::new(nodes, SVector::zeros()),
        )
    };
    world.resource_mut::<LoadStep>().factor = 0.0;
    let _ = world.try_run_schedule(FixedLoadsSchedule); // absent: no load module added to it
    let _ = world.try_run_schedule(SumFixedLoadsSchedule); // absent: not decomposed
    world.resource_mut::<LoadStep>().factor = 1.0;
    let fixed = std::mem::replace(
        &mut world.resource_mut::<GridFields<D>>().external_force,
        unit,
    );
    let mut fields = world.resource_mut::<GridFields<D>>();
    for (node, held) in fixed.written() {
        fields.external_force[node] -= held;
    }
    world.resource_mut::<ArcLength<D>>().fixed = fixed.to_vec();
}

/// `Hook::BeforeSolve`, before the Newton loop (so after `Hook::Loads`): keeps f̂ and puts
/// f_ext = λ_n f̂ and λ_n back.
pub fn take_reference_load<const D: usize>(
    mut arc: ResMut<ArcLength<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut step: ResMut<LoadStep>,
    mut status: ResMut<RunStatus>,
    mut warnings: ResMut<Warnings>,
    newton: Res<Newton>,
) {
    let (arc, fields) = (&mut *arc, &mut *fields);
    arc.reference = fields.external_force.to_vec();
    arc.reference_dofs.clear();
    arc.reference_dofs.resize(fields.dof_count, 0.0);
    for (node, dofs) in fields.dofs.written() {
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                arc.reference_dofs[dof as usize] = arc.reference[node][c];
            }
        }
    }
    // on a grid split among processes: whether any process's free DOFs carry f̂
    let loaded = f64::from(u8::from(arc.reference_dofs.iter().any(|&f| f != 0.0)));
    let loaded = match OverProcesses::new(fields, newton.shared_grid.as_deref()).sum([loaded]) {
        Ok([loaded]) => loaded > 0.0,
        Err(why) => {
            status.fail(sum_failed(step.number, why));
            return;
        }
    };
    if !loaded {
        status.fail(SolverError::Module {
            step: step.number,
            what: "arc-length control: the loads at load factor 1 put no force on a free \
                   degree of freedom (arc-length controls tractions, point loads and a body \
                   force that follow the load factor; held loads are not controlled)"
                .to_string(),
            recoverable: false,
        });
        return;
    }
    arc.set_external(&mut fields.external_force, arc.start);
    step.factor = arc.start;
    if arc.rebalancing {
        arc.rebalancing = arc.may_rebalance(step.number, &mut warnings);
    }
}

/// `Hook::Convergence`, after the check: the predictor is always taken (at Δu = 0 the residual
/// is the previous step's converged one), and a converged increment that turns back along the
/// path is refused (recoverable: the arc is cut): Δu·Δu_{n−1} < 0, or unloading, Δλ < 0 with
/// f̂·Δu < 0 (the load and the displacement it works on both fall). Such a point is on the arc
/// and in equilibrium, but it is the path already traced (typically the elastic unloading
/// branch past a plastic limit). A genuine snap-back (load and displacement falling together)
/// is refused the same way: this control does not follow one.
pub fn keep_going_forward<const D: usize>(
    arc: Res<ArcLength<D>>,
    fields: Res<GridFields<D>>,
    mut newton: ResMut<Newton>,
    step: Res<LoadStep>,
    mut status: ResMut<RunStatus>,
) {
    if newton.iterations == 0 {
        newton.converged = false;
        return;
    }
    if !newton.converged || arc.previous.is_empty() {
        return;
    }
    // Δu and f̂ by node are this process's nodes' (Δu_{n−1} is whole: `accept`)
    let sums = OverProcesses::new(&fields, newton.shared_grid.as_deref());
    let parts = [
        sums.node_dot(&arc.current, &arc.current),
        sums.node_dot(&arc.reference, &arc.reference),
        sums.node_dot(&arc.current, &arc.previous),
        sums.node_dot(&arc.current, &arc.reference),
    ];
    let [current, reference, along, work] = match sums.sum(parts) {
        Ok(sums) => sums,
        Err(why) => {
            status.fail(sum_failed(step.number, why));
            return;
        }
    };
    let (current, previous, reference) = (current.sqrt(), length(&arc.previous), reference.sqrt());
    let unloading = arc.factor < arc.start && turns_back(work, current, reference);
    if turns_back(along, current, previous) || unloading {
        newton.converged = false;
        let why = if unloading {
            format!("the load and the displacement under it both fall (f̂·Δu = {work:.3e})")
        } else {
            format!("Δu·Δu_prev = {along:.3e} < 0")
        };
        // held loads whose imbalance on each step's grid the arc has to absorb (nodes newly
        // reached by domains, with slivers of support) make it take its other root:
        // removing that imbalance first is what has been seen to help (docs/plasticity.md)
        let hint = if arc.fixed_loads && arc.rebalance == Rebalance::Off {
            "; the scene holds loads and asks for rebalance: \"off\": their out-of-balance force \
             on each step's grid then steers the arc (docs/plasticity.md, \"Past the limit \
             load\"); the default, rebalance: \"auto\", removes it before the arc where it needs \
             a correction at least as long as the arc (\"fixed\": on every step)"
        } else {
            ""
        };
        let what = if arc.on_plateau() {
            // a perfectly plastic plateau: λ flat while u grows, and Newton lands on the
            // elastic unloading branch about it (module docs, "A plateau")
            format!(
                "arc-length control: the limit load was reached: the load factor stays at its \
                 largest value, {:.6e}, while the displacement grows (the current stiffness \
                 parameter, the last step's Δλ/‖Δu‖ over the first's, is {:.1e}: a plateau); \
                 this attempt did not go on along it ({why}, load factor {:.6e}); the arc is cut",
                arc.peak,
                arc.stiffness_parameter().unwrap_or(f64::NAN),
                step.factor
            )
        } else {
            format!(
                "arc-length control: the converged increment turns back along the path traced \
                 ({why}, load factor {:.6e}); the arc is cut{hint}",
                step.factor
            )
        };
        status.fail(SolverError::Module {
            step: step.number,
            what,
            recoverable: true,
        });
    }
}

/// Below this in size, the current stiffness parameter ([`ArcLength::stiffness_parameter`]) of
/// a step at the largest load factor means a plateau: the limit load is reached
/// ([`ArcLength::on_plateau`]; measured on the staged perfectly plastic block: see the module
/// docs, "A plateau").
pub const PLATEAU_STIFFNESS: f64 = 1e-3;

/// Below −this times |a| |b|, a dot product a·b counts as negative in the turn-back test
/// ([`turns_back`]; the module docs say why round-off is far smaller and a turn-back far larger).
pub const TURN_BACK_COSINE: f64 = 1e-6;

/// Whether `dot` = a·b, with |a| = `a` and |b| = `b`, is negative beyond round-off: its cosine
/// below −[`TURN_BACK_COSINE`] (false when a length is zero).
pub fn turns_back(dot: f64, a: f64, b: f64) -> bool {
    a > 0.0 && b > 0.0 && dot < -TURN_BACK_COSINE * a * b
}

/// Above this, the out-of-balance force a step starts with (relative to the external force of
/// the last converged step) gets a warning (module docs, "A step that starts out of balance").
pub const START_IMBALANCE: f64 = 0.1;

/// `Hook::Convergence`, before [`keep_going_forward`]: at the step's first check (Δu = 0,
/// f_ext = λ_n f̂) keeps the out-of-balance force it starts with, relative to λ_n f̂
/// (`initial_imbalance`; none at λ_n = 0), and warns once per run when it exceeds
/// [`START_IMBALANCE`].
pub fn record_start_imbalance<const D: usize>(
    mut arc: ResMut<ArcLength<D>>,
    fields: Res<GridFields<D>>,
    newton: Res<Newton>,
    step: Res<LoadStep>,
    mut warnings: ResMut<Warnings>,
    mut status: ResMut<RunStatus>,
) {
    if newton.iterations != 0 || newton.residuals.len() != 1 {
        return;
    }
    arc.start_imbalance = match imbalance(&fields, &newton) {
        Ok(imbalance) => imbalance,
        Err(why) => {
            status.fail(sum_failed(step.number, why));
            return;
        }
    };
    // the first step's start residual is the held loads' (none without them), not a crossing
    let first = arc.previous.is_empty();
    if let Some(imbalance) = arc.start_imbalance
        && imbalance > START_IMBALANCE
        && !arc.warned_imbalance
        && !first
    {
        arc.warned_imbalance = true;
        warnings.0.push(imbalance_warning(step.number, imbalance));
    }
}

/// ‖f_ext − f_int‖_free / ‖f_ext‖ of the iterate just checked ([`start_imbalance`]; on a grid
/// split among processes summed over them, each node on its owner: collective).
fn imbalance<const D: usize>(
    fields: &GridFields<D>,
    newton: &Newton,
) -> Result<Option<f64>, String> {
    let sums = OverProcesses::new(fields, newton.shared_grid.as_deref());
    let free = (newton.residual.iter().enumerate())
        .filter(|(dof, _)| sums.counted.get(*dof).is_none_or(|c| *c))
        .map(|(_, r)| r * r)
        .sum::<f64>();
    let external = (fields.external_force.written())
        .filter(|&(node, _)| fields.active[node] && sums.counts(node))
        .map(|(_, f)| f.norm_squared())
        .sum::<f64>();
    let [free, external] = sums.sum([free, external])?;
    Ok(start_imbalance(free.sqrt(), external.sqrt()))
}

/// `Hook::Convergence`, after [`record_start_imbalance`] and before [`keep_going_forward`]
/// (scheduled only with `rebalance`): while the attempt removes its start residual, a
/// converged iterate ends the rebalancing instead of the step: its state (Δu_c, λ_c) becomes
/// the arc's origin and the iterations go on with the arc's predictor. With λ free, a
/// converged rebalancing that unloads (λ_c < λ_n with f̂·Δu_c < 0 beyond round-off,
/// [`turns_back`]) further than the last step went, ‖Δu_c‖ > ‖Δu_{n−1}‖, is refused: it went
/// back down the path already traced (a small unloading is the equilibrium of the new grid). A rebalancing that is
/// refused, runs out of iterations or fails otherwise fails the attempt (recoverable), and
/// the step's next attempts go without it ([`take_reference_load`]): cutting the arc would
/// repeat it exactly, since it starts from the committed state and does not depend on the arc.
pub fn finish_rebalance<const D: usize>(
    mut arc: ResMut<ArcLength<D>>,
    fields: Res<GridFields<D>>,
    mut newton: ResMut<Newton>,
    settings: Res<NewtonSettings>,
    step: Res<LoadStep>,
    mut status: ResMut<RunStatus>,
) {
    if !arc.rebalancing {
        return;
    }
    if newton.converged {
        newton.converged = false;
        let origin = free_part(&fields);
        let sums = OverProcesses::new(&fields, newton.shared_grid.as_deref());
        let parts = [
            sums.node_dot(&origin, &arc.reference),
            sums.node_dot(&origin, &origin),
        ];
        let (work, moved, imbalance) = match sums
            .sum(parts)
            .and_then(|[work, moved]| Ok((work, moved.sqrt(), imbalance(&fields, &newton)?)))
        {
            Ok(figures) => figures,
            Err(why) => {
                status.fail(sum_failed(step.number, why));
                return;
            }
        };
        let last = length(&arc.previous);
        if arc.factor < arc.start && turns_back(work, moved, length(&arc.reference)) && moved > last
        {
            // λ free: the nearest equilibrium is on the unloading branch, the path traced
            status.fail(SolverError::Module {
                step: step.number,
                what: format!(
                    "arc-length control: the rebalancing before the arc unloads (the load \
                     factor falls from {:.6e} to {:.6e} with f̂·Δu = {work:.3e}, and ‖Δu‖ = \
                     {moved:.3e} exceeds the last step's {last:.3e}): the nearest equilibrium \
                     is back on the path already traced",
                    arc.start, arc.factor
                ),
                recoverable: true,
            });
            return;
        }
        arc.rebalancing = false;
        arc.rebalancing_step = None;
        arc.origin = origin;
        arc.start = arc.factor;
        arc.rebalanced = Some(Rebalanced {
            iterations: newton.iterations,
            imbalance,
            factor: arc.factor,
        });
    } else if newton.iterations >= settings.max_iterations {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!(
                "arc-length control: the rebalancing before the arc (rebalance: \"{}\") did \
                 not converge in {} iterations (residuals {:.1e} to {:.1e}): the committed \
                 state has no equilibrium near it on this step's grid{}; the step's next \
                 attempts go without",
                arc.rebalancing_mode().word(),
                newton.iterations,
                newton.residuals.first().copied().unwrap_or(f64::NAN),
                newton.residuals.last().copied().unwrap_or(f64::NAN),
                if arc.rebalancing_mode() == Rebalance::Fixed {
                    " at the same load factor (rebalance: \"free\" lets it move)"
                } else {
                    ""
                }
            ),
            recoverable: true,
        });
    }
}

/// ‖r‖ / ‖f_ext‖ at a step's start; `None` without an external force or for a value that is
/// not finite.
pub fn start_imbalance(residual: f64, external: f64) -> Option<f64> {
    let ratio = residual / external;
    (external > 0.0 && ratio.is_finite()).then_some(ratio)
}

/// The warning of a step that starts with the out-of-balance force `imbalance`.
pub fn imbalance_warning(step: usize, imbalance: f64) -> String {
    format!(
        "step {step} starts out of balance: the out-of-balance force of the converged state \
         on the new grid is {imbalance:.3e} of the external force (above {START_IMBALANCE}; \
         summary.json steps' initial_imbalance). Points crossed cell faces, where linear \
         MPM's gradients jump: near a limit load the answer may depend on the resolution; \
         check it with a finer grid or a smoother basis (docs/plasticity.md, \"Past the limit \
         load\")"
    )
}

/// `Hook::AfterLinearSolve`, after `K δu_r = r` (already added to Δu): solves `K δu_f = f̂`, finds
/// δλ (module docs) and moves the iterate to Δu + δλ δu_f, λ + δλ, f_ext = λ f̂.
pub fn correct_load_factor<const D: usize>(
    mut arc: ResMut<ArcLength<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut step: ResMut<LoadStep>,
    mut status: ResMut<RunStatus>,
    mut warnings: ResMut<Warnings>,
) {
    let (arc, fields, newton) = (&mut *arc, &mut *fields, &mut *newton);
    if newton.iterations == arc.corrected {
        return; // no solve in this iteration
    }
    arc.corrected = newton.iterations;
    if arc.rebalancing && arc.rebalancing_mode() == Rebalance::Fixed {
        return; // Δu += δu_r at λ = λ_n
    }
    let residual_part = newton.residual.clone();
    let mut increment = vec![0.0; residual_part.len()];
    let mut previous = vec![0.0; residual_part.len()];
    // the arc's predictor has Δu − Δu_c = 0 exactly (a difference of the sums would not be)
    let predictor = arc.current.is_empty();
    for (node, dofs) in fields.dofs.written() {
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                let dof = dof as usize;
                if !predictor || arc.origin.is_empty() {
                    let origin = arc.origin.get(node).map_or(0.0, |u| u[c]);
                    increment[dof] = fields.increment[node][c] - residual_part[dof] - origin;
                }
                previous[dof] = arc.previous.get(node).map_or(0.0, |u| u[c]);
            }
        }
    }
    let mut load_part = arc.reference_dofs.clone();
    let solved = newton
        .solver
        .solve(&newton.matrix, newton.symmetric, &mut load_part);
    // what the solver changed on its own in this solve (PETSc's fallback), as Newton's solve
    // says it (`stages::newton::solve_linear_system`)
    if let Some(notice) = newton.solver.take_notice() {
        warnings
            .0
            .push(format!("load step {}: {notice}", step.number));
    }
    if let Err(why) = solved {
        status.fail(SolverError::LinearSolve {
            step: step.number,
            iteration: newton.iterations,
            why: format!("arc-length, K δu_f = f̂: {why}"),
        });
        return;
    }
    // every product below over the whole problem (collective on a grid split among processes)
    let sums = OverProcesses::new(fields, newton.shared_grid.as_deref());
    let dot = |u: &[f64], v: &[f64]| sums.dot(u, v);
    if arc.rebalancing {
        // λ free, no arc: the shortest correction δu_r + δλ δu_f
        let delta = match shortest_correction_with(&dot, &residual_part, &load_part) {
            Ok(delta) => delta,
            Err(why) => {
                status.fail(sum_failed(step.number, why));
                return;
            }
        };
        let Some(delta) = delta else {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!(
                    "arc-length control, rebalancing: no load-factor correction at iteration {} \
                     (δu_f = 0, or a value is not finite)",
                    newton.iterations
                ),
                recoverable: false,
            });
            return;
        };
        add_load_part(fields, &load_part, delta);
        set_factor(arc, fields, &mut step, arc.factor + delta);
        return;
    }
    // the arc's figures: whether to rebalance first, the predictor's sign, δλ
    let mut correction = || -> Result<Option<Option<(f64, Root)>>, String> {
        if arc.radius <= 0.0 {
            arc.radius = arc.first_increment.abs() * dot(&load_part, &load_part)?.sqrt();
        }
        if arc.rebalance == Rebalance::Auto
            && predictor
            && arc.origin.is_empty()
            && dot(&residual_part, &residual_part)? >= arc.radius * arc.radius
            && arc.may_rebalance(step.number, &mut warnings)
        {
            // the start correction is at least the arc ("Held loads"): the step rebalances
            // at λ_n first, this iteration its first (Δu += δu_r at λ_n is done)
            arc.rebalancing = true;
            return Ok(None);
        }
        let sign = if arc.previous.is_empty() {
            arc.first_increment.signum()
        } else if dot(&previous, &load_part)? < 0.0 {
            -1.0
        } else {
            1.0
        };
        load_correction_with(
            &dot,
            &increment,
            &residual_part,
            &load_part,
            arc.radius,
            sign,
        )
        .map(Some)
    };
    let correction = match correction() {
        Ok(Some(correction)) => correction,
        Ok(None) => return,
        Err(why) => {
            status.fail(sum_failed(step.number, why));
            return;
        }
    };
    let Some((delta, root)) = correction else {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!(
                "arc-length control: no load-factor correction at iteration {} (the \
                 linearised constraint is singular, or a value is not finite)",
                newton.iterations
            ),
            recoverable: true,
        });
        return;
    };
    if root == Root::Linearised && newton.iterations > 1 {
        arc.linearised += 1;
    }
    add_load_part(fields, &load_part, delta);
    set_factor(arc, fields, &mut step, arc.factor + delta);
    // the arc's Δu by node, from its origin
    arc.current = free_part(fields);
    for (current, origin) in arc.current.iter_mut().zip(&arc.origin) {
        *current -= origin;
    }
}

/// δλ of the shortest correction δu_r + δλ δu_f (normal flow: orthogonal to δu_f),
/// −(δu_f·δu_r)/(δu_f·δu_f); `None` when δu_f = 0 or a value is not finite.
pub fn shortest_correction(residual_part: &[f64], load_part: &[f64]) -> Option<f64> {
    let dot = |u: &[f64], v: &[f64]| Ok(dot(u, v));
    shortest_correction_with(&dot, residual_part, load_part).unwrap_or(None)
}

/// [`shortest_correction`] with the inner product `dot` (as [`load_correction_with`]).
pub fn shortest_correction_with(
    dot: &InnerProduct<'_>,
    residual_part: &[f64],
    load_part: &[f64],
) -> Result<Option<f64>, String> {
    let delta = -dot(load_part, residual_part)? / dot(load_part, load_part)?;
    Ok(delta.is_finite().then_some(delta))
}

/// Δu += δλ δu_f at the free DOFs.
fn add_load_part<const D: usize>(fields: &mut GridFields<D>, load_part: &[f64], delta: f64) {
    for (node, dofs) in fields.dofs.written() {
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                fields.increment[node][c] += delta * load_part[dof as usize];
            }
        }
    }
}

/// The iterate's load factor λ: f_ext = λ f̂.
fn set_factor<const D: usize>(
    arc: &mut ArcLength<D>,
    fields: &mut GridFields<D>,
    step: &mut LoadStep,
    factor: f64,
) {
    arc.factor = factor;
    step.factor = arc.factor;
    arc.set_external(&mut fields.external_force, factor);
}

/// Δu by node, with the inactive and constrained components (which carry none) zero (dense:
/// the arc keeps Δu_{n−1} whole on every process, module docs).
fn free_part<const D: usize>(fields: &GridFields<D>) -> Vec<SVector<f64, D>> {
    let mut free = fields.increment.clone();
    for (node, u) in free.written_mut() {
        for (c, &dof) in fields.dofs[node].iter().enumerate() {
            if dof == NO_DOF {
                u[c] = 0.0;
            }
        }
    }
    free.to_vec()
}

/// The arc-length step policy's state between steps ([`ArcLengthControl::state`]), put into
/// the world by the run driver, which keeps the policy, so that the arc module's checkpoint
/// part ([`save_arc_state`]) saves it with the arc's own.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct ArcControlState(pub Vec<f64>);

/// `checkpoint::CheckpointPart::save` of the arc (`effects::arc_length`): the policy's state
/// ([`ArcControlState`], length first), then the first load increment, the two warned flags
/// and Δu_{n−1} by node (count first).
pub fn save_arc_state<const D: usize>(world: &mut World) -> Vec<f64> {
    let control = world
        .get_resource::<ArcControlState>()
        .map_or_else(Vec::new, |s| s.0.clone());
    let arc = world.resource::<ArcLength<D>>();
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    let mut values = vec![control.len() as f64];
    values.extend(control);
    values.extend([
        arc.first_increment,
        flag(arc.warned_imbalance),
        flag(arc.warned_unbalanced),
        arc.previous.len() as f64,
    ]);
    for u in &arc.previous {
        values.extend(u.iter());
    }
    values
}

/// `checkpoint::CheckpointPart::restore` of [`save_arc_state`]: the arc's state back, and the
/// policy's as an [`ArcControlState`] for the driver.
pub fn restore_arc_state<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let count = |x: f64| {
        (x.is_finite() && x >= 0.0 && x.fract() == 0.0)
            .then_some(x as usize)
            .ok_or_else(|| format!("{x} is not a count"))
    };
    let (&length, rest) = values.split_first().ok_or("no numbers saved")?;
    let length = count(length)?;
    if length > rest.len() {
        return Err(format!(
            "{length} numbers of the step policy, {} saved",
            rest.len()
        ));
    }
    let (control, rest) = rest.split_at(length);
    let &[
        first,
        warned_imbalance,
        warned_unbalanced,
        nodes,
        ref previous @ ..,
    ] = rest
    else {
        return Err(format!(
            "{} numbers after the step policy's, 4 or more expected",
            rest.len()
        ));
    };
    let previous: Vec<SVector<f64, D>> = crate::checkpoint::records(previous, D, count(nodes)?)?
        .map(SVector::from_column_slice)
        .collect();
    world.insert_resource(ArcControlState(control.to_vec()));
    let mut arc = world.resource_mut::<ArcLength<D>>();
    arc.first_increment = first;
    arc.warned_imbalance = warned_imbalance != 0.0;
    arc.warned_unbalanced = warned_unbalanced != 0.0;
    arc.previous = previous;
    arc.rebalancing_step = None;
    Ok(())
}

/// Why an arc-length run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArcEnd {
    /// λ reached `max_load_factor`.
    MaxLoadFactor,
    /// λ fell back to zero after its peak: the load is shed.
    Unloaded,
}

/// The arc-length step policy (pure; see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ArcLengthControl {
    pub spec: ArcLengthSpec,
    pub max_cuts: usize,
    /// Δl of the next step; 0 before the first step sized it.
    radius: f64,
    /// The first step's load increment while its arc is not known (halved by cuts).
    first_increment: f64,
    cuts: usize,
    /// The largest λ of a converged step, and the step.
    peak: Option<(f64, usize)>,
    /// λ of the last converged step.
    last: f64,
    end: Option<ArcEnd>,
    /// Iterations of the converged steps whose δλ came from the linearised constraint.
    linearised: usize,
    /// The largest arc of a converged step, and the last one's.
    largest_arc: f64,
    last_arc: f64,
}

/// Below this fraction of the largest arc, the last converged arc means the path is no longer
/// traced: cuts have shrunk the steps until they barely move ([`ArcLengthControl::stalled`]).
pub const STALLED_ARC: f64 = 1e-2;

impl ArcLengthControl {
    pub fn new(spec: ArcLengthSpec, max_cuts: usize, first_increment: f64) -> Self {
        Self {
            spec,
            max_cuts,
            radius: 0.0,
            first_increment,
            cuts: 0,
            peak: None,
            last: 0.0,
            end: None,
            linearised: 0,
            largest_arc: 0.0,
            last_arc: 0.0,
        }
    }

    /// Starts a load step: the step's first attempt; returns λ_n.
    pub fn begin(&mut self) -> f64 {
        self.cuts = 0;
        self.last
    }

    /// The next attempt: (λ_n, the arc Δl, 0 while the first step sizes it, and the load
    /// increment it is sized from).
    pub fn begin_attempt(&self) -> (f64, f64, f64) {
        (self.last, self.radius, self.first_increment)
    }

    /// The attempt converged at λ = `factor` after `iterations` Newton iterations, on the arc
    /// `radius`, with `linearised` iterations off the arc: records it and sizes the next arc.
    pub fn succeeded(
        &mut self,
        step: usize,
        factor: f64,
        iterations: usize,
        radius: f64,
        linearised: usize,
    ) {
        self.linearised += linearised;
        self.largest_arc = self.largest_arc.max(radius);
        self.last_arc = radius;
        let scale = (self.spec.target_iterations as f64 / iterations.max(1) as f64).sqrt();
        self.radius = radius * scale.clamp(0.5, 2.0);
        if self.peak.is_none_or(|(peak, _)| factor > peak) {
            self.peak = Some((factor, step));
        }
        self.last = factor;
        if factor >= self.spec.max_load_factor {
            self.end = Some(ArcEnd::MaxLoadFactor);
        } else if factor <= 0.0 && self.peak.is_some_and(|(peak, _)| peak > 0.0) {
            self.end = Some(ArcEnd::Unloaded);
        }
    }

    /// The attempt failed (`recoverable`: a shorter arc may succeed): whether to try again
    /// with half the arc.
    pub fn failed(&mut self, recoverable: bool) -> bool {
        if !recoverable || self.cuts >= self.max_cuts {
            return false;
        }
        self.cuts += 1;
        if self.radius > 0.0 {
            self.radius *= 0.5;
        } else {
            self.first_increment *= 0.5;
        }
        true
    }

    /// Its state between steps as numbers (a checkpoint's part, [`ArcControlState`]): the
    /// next arc, the first increment, the peak and its step (NaN, −1: none), the last λ, the
    /// end (0 none, 1 max_load_factor, 2 unloaded), the linearised iterations, the largest and
    /// the last arc.
    pub fn state(&self) -> Vec<f64> {
        let (peak, at) = self.peak.map_or((f64::NAN, -1.0), |(p, s)| (p, s as f64));
        let end = match self.end {
            None => 0.0,
            Some(ArcEnd::MaxLoadFactor) => 1.0,
            Some(ArcEnd::Unloaded) => 2.0,
        };
        vec![
            self.radius,
            self.first_increment,
            peak,
            at,
            self.last,
            end,
            self.linearised as f64,
            self.largest_arc,
            self.last_arc,
        ]
    }

    /// Restores [`ArcLengthControl::state`] (the scene's options stay this policy's).
    pub fn restore(&mut self, state: &[f64]) -> Result<(), String> {
        let &[
            radius,
            first,
            peak,
            at,
            last,
            end,
            linearised,
            largest,
            last_arc,
        ] = state
        else {
            return Err(format!(
                "the arc-length step policy: {} numbers saved, 9 expected",
                state.len()
            ));
        };
        self.radius = radius;
        self.first_increment = first;
        self.peak = (at >= 0.0).then_some((peak, at as usize));
        self.last = last;
        self.end = match end as u8 {
            1 => Some(ArcEnd::MaxLoadFactor),
            2 => Some(ArcEnd::Unloaded),
            _ => None,
        };
        self.linearised = linearised as usize;
        self.largest_arc = largest;
        self.last_arc = last_arc;
        self.cuts = 0;
        Ok(())
    }

    /// The current step's cuts.
    pub fn cuts(&self) -> usize {
        self.cuts
    }

    /// Why the run ended, if it did.
    pub fn end(&self) -> Option<ArcEnd> {
        self.end
    }

    /// The largest λ of a converged step and its step number.
    pub fn peak(&self) -> Option<(f64, usize)> {
        self.peak
    }

    /// Whether λ has come down from its peak (the limit load was passed): by more than a
    /// millionth of the peak.
    pub fn passed_peak(&self) -> bool {
        self.peak
            .is_some_and(|(peak, _)| peak > 0.0 && self.last < peak * (1.0 - 1e-6))
    }

    /// The last converged arc over the largest, when it is below [`STALLED_ARC`]: the steps
    /// no longer move along the path (on a footing past its peak, Newton keeps landing on the
    /// elastic unloading branch, which is refused, and the cuts shrink the arc), so the end of
    /// the curve is not a result.
    pub fn stalled(&self) -> Option<f64> {
        let ratio = self.last_arc / self.largest_arc;
        (self.largest_arc > 0.0 && ratio < STALLED_ARC).then_some(ratio)
    }

    /// The warning of a [`ArcLengthControl::stalled`] run.
    pub fn stalled_warning(&self) -> Option<String> {
        self.stalled().map(|ratio| {
            format!(
                "arc-length control: the last arc is {ratio:.1e} of the largest (step cuts \
                 shrank it): the last steps barely moved, so the load-displacement path there \
                 is not traced and the end of the curve is not a result (the predictor is the \
                 elastic one; docs/plasticity.md, \"Past the limit load\")"
            )
        })
    }

    /// The run's record for `summary.json` (`"arc_length"`).
    pub fn to_json(&self) -> serde_json::Value {
        let number =
            |x: f64| serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, Into::into);
        serde_json::json!({
            "peak_load_factor": self.peak.map(|(peak, _)| number(peak)),
            "peak_step": self.peak.map(|(_, step)| step),
            "passed_limit": self.passed_peak() || self.end == Some(ArcEnd::Unloaded),
            "end": match self.end {
                Some(ArcEnd::MaxLoadFactor) => "max_load_factor",
                Some(ArcEnd::Unloaded) => "unloaded",
                None => "steps",
            },
            "linearised_iterations": self.linearised,
            "stalled_arc_ratio": self.stalled().map(number),
            "report": self.report(),
        })
    }

    /// One line on the run for the log and `summary.json`.
    pub fn report(&self) -> String {
        let Some((peak, at)) = self.peak else {
            return "arc-length control: no step converged".to_string();
        };
        let how = match self.end {
            Some(ArcEnd::MaxLoadFactor) => format!(
                "it ended at max_load_factor {} without passing a limit load",
                self.spec.max_load_factor
            ),
            Some(ArcEnd::Unloaded) => {
                "it passed the limit load and ended when the load factor fell back to zero"
                    .to_string()
            }
            None if self.passed_peak() => format!(
                "it passed the limit load (the last load factor is {:.6e}, {:.3} % below the peak)",
                self.last,
                100.0 * (1.0 - self.last / peak)
            ),
            None => "it did NOT pass a limit load: the load factor was still rising at the \
                     last step, so the peak is not the limit load (give more steps or a longer \
                     first arc)"
                .to_string(),
        };
        format!("arc-length control: the largest load factor was {peak:.6e} at step {at}; {how}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_whose_arc_shrank_to_nothing_is_called_stalled() {
        let spec = ArcLengthSpec {
            target_iterations: 5,
            max_load_factor: 10.0,
            ..ArcLengthSpec::default()
        };
        let mut control = ArcLengthControl::new(spec, 8, 0.1);
        control.succeeded(1, 1.0, 5, 0.2, 0);
        control.succeeded(2, 2.0, 5, 0.2, 0);
        assert_eq!(control.stalled(), None);
        control.succeeded(3, 1.9, 5, 0.2 * STALLED_ARC * 2.0, 0);
        assert_eq!(control.stalled(), None, "above the threshold");
        control.succeeded(4, 1.9, 5, 0.2 * STALLED_ARC / 2.0, 0);
        let ratio = control.stalled().expect("stalled");
        assert!((ratio - STALLED_ARC / 2.0).abs() < 1e-15, "{ratio}");
        assert!(control.stalled_warning().unwrap().contains("not traced"));
    }

    #[test]
    fn the_policy_state_round_trips() {
        let mut control = ArcLengthControl::new(ArcLengthSpec::default(), 8, 0.1);
        let mut fresh = control.clone();
        fresh.restore(&control.state()).unwrap();
        assert_eq!(fresh, control, "before any step");
        control.succeeded(1, 1.0, 5, 0.2, 1);
        control.succeeded(2, 0.5, 3, 0.1, 0);
        control.succeeded(3, -0.1, 3, 0.1, 0);
        let mut restored = ArcLengthControl::new(ArcLengthSpec::default(), 8, 0.1);
        restored.restore(&control.state()).unwrap();
        assert_eq!(restored, control);
        assert_eq!(restored.end(), Some(ArcEnd::Unloaded));
        assert!(restored.restore(&[1.0, 2.0]).is_err());
    }

    #[test]
    fn a_round_off_negative_dot_product_is_not_a_turn_back() {
        // the collapsed arc of the 8-cell footing: f̂·Δu ≈ −2e-15 on tiny increments
        let (a, b) = (1e-6, 10.0);
        assert!(!turns_back(-2e-15, a, b), "cosine −2e-10: round-off");
        assert!(!turns_back(-0.99 * TURN_BACK_COSINE * a * b, a, b));
        assert!(turns_back(-1.01 * TURN_BACK_COSINE * a * b, a, b));
        // a real turn-back, onto the unloading branch: a cosine of −0.1
        assert!(turns_back(-0.1 * a * b, a, b));
        assert!(!turns_back(0.0, 0.0, b) && !turns_back(-1e-300, 0.0, b));
    }

    #[test]
    fn a_large_start_imbalance_is_measured_and_named() {
        assert_eq!(start_imbalance(1.0, 0.0), None, "no external force");
        assert_eq!(start_imbalance(f64::NAN, 1.0), None);
        assert_eq!(start_imbalance(0.43, 1.0), Some(0.43));
        let warning = imbalance_warning(9, 0.43);
        assert!(
            warning.contains("step 9") && warning.contains("4.300e-1"),
            "{warning}"
        );
        assert!(warning.contains("crossed cell faces"));
    }

    #[test]
    fn the_free_rebalancing_takes_the_shortest_correction() {
        let (residual, load) = ([1.0, 2.0], [3.0, -1.0]);
        let delta = shortest_correction(&residual, &load).unwrap();
        let change: Vec<f64> = (0..2).map(|i| residual[i] + delta * load[i]).collect();
        // orthogonal to δu_f: no other δλ gives a shorter change
        assert!(dot(&change, &load).abs() < 1e-15, "{change:?}");
        assert_eq!(shortest_correction(&residual, &[0.0, 0.0]), None);
        for word in Rebalance::WORDS {
            assert_eq!(Rebalance::from_word(word).map(Rebalance::word), Some(word));
        }
        assert_eq!(Rebalance::from_word("on"), None);
    }

    #[test]
    fn the_predictor_goes_the_asked_way_on_the_arc() {
        let load = [3.0, 4.0]; // ‖δu_f‖ = 5
        for sign in [1.0, -1.0] {
            let (delta, root) =
                load_correction(&[0.0, 0.0], &[0.0, 0.0], &load, 2.0, sign).expect("a predictor");
            assert_eq!(root, Root::Arc);
            assert!((delta - sign * 0.4).abs() < 1e-15, "{delta}");
        }
    }

    #[test]
    fn the_corrector_lands_on_the_arc_and_keeps_the_direction() {
        let (increment, residual, load) = ([1.0, 0.0], [-0.1, 0.05], [0.3, 1.0]);
        let (delta, root) = load_correction(&increment, &residual, &load, 1.0, 1.0).unwrap();
        assert_eq!(root, Root::Arc);
        let new: Vec<f64> = (0..2)
            .map(|i| increment[i] + residual[i] + delta * load[i])
            .collect();
        assert!((dot(&new, &new) - 1.0).abs() < 1e-14);
        // the other root would turn the increment back: a negative cosine
        assert!(dot(&new, &increment) > 0.9);
    }

    #[test]
    fn without_a_real_root_the_change_is_orthogonal_to_the_increment() {
        // a residual far off the arc: |Δu + δu_r| = 3 against Δl = 1, δu_f small
        let (increment, residual, load) = ([1.0, 0.0], [2.0, 1.0], [0.1, 0.1]);
        let (delta, root) = load_correction(&increment, &residual, &load, 1.0, 1.0).unwrap();
        assert_eq!(root, Root::Linearised);
        let change: Vec<f64> = (0..2).map(|i| residual[i] + delta * load[i]).collect();
        assert!(dot(&change, &increment).abs() < 1e-15);
        // singular: δu_f orthogonal to Δu
        assert_eq!(
            load_correction(&increment, &residual, &[0.0, 0.1], 1.0, 1.0),
            None
        );
    }

    #[test]
    fn the_policy_scales_halves_and_ends_the_run() {
        let spec = ArcLengthSpec {
            target_iterations: 4,
            max_load_factor: 2.0,
            ..ArcLengthSpec::default()
        };
        let mut control = ArcLengthControl::new(spec, 2, 0.1);
        assert_eq!(control.begin(), 0.0);
        assert_eq!(control.begin_attempt(), (0.0, 0.0, 0.1));
        // the first step fails before its arc is known: the increment is halved
        assert!(control.failed(true));
        assert_eq!(control.begin_attempt().2, 0.05);
        control.succeeded(1, 0.05, 16, 8.0, 0);
        // 16 iterations against 4: the arc halves (√(1/4))
        assert_eq!(control.begin(), 0.05);
        assert_eq!(control.begin_attempt(), (0.05, 4.0, 0.05));
        control.succeeded(2, 1.5, 1, 4.0, 1);
        // one iteration: doubled at most
        control.begin();
        assert_eq!(control.begin_attempt().1, 8.0);
        assert!(control.failed(true) && control.failed(true) && !control.failed(true));
        assert_eq!(control.begin_attempt().1, 2.0);
        assert!(!control.failed(false));
        control.succeeded(3, 1.2, 4, 2.0, 0);
        assert!(control.passed_peak());
        assert_eq!(control.peak(), Some((1.5, 2)));
        assert!(control.report().contains("passed the limit load"));
        control.succeeded(4, -0.1, 4, 2.0, 0);
        assert_eq!(control.end(), Some(ArcEnd::Unloaded));
        assert_eq!(control.to_json()["linearised_iterations"], 1);
        assert_eq!(control.to_json()["passed_limit"], true);
        let mut rising = ArcLengthControl::new(spec, 2, 0.1);
        rising.succeeded(1, 2.5, 4, 1.0, 0);
        assert_eq!(rising.end(), Some(ArcEnd::MaxLoadFactor));
        let mut short = ArcLengthControl::new(spec, 2, 0.1);
        short.succeeded(1, 0.5, 4, 1.0, 0);
        assert!(short.report().contains("did NOT pass"));
        assert_eq!(short.to_json()["end"], "steps");
    }
}
