//! Benchmark: how the cost of a load step grows with the number of points, per stage, for each
//! linear-solver backend and for 1 and 2 threads, side by side in one process.
//!
//! Self-weight blocks (B-spline q = 2, 2 x 2 (x 2) points per cell, rollers on the sides, base
//! fixed: the uniaxial-strain column, so every run also prints its eq. 15 error against the
//! semi-analytical column and a wrong answer shows), for the sizes given:
//!
//! ```sh
//! cargo run --release --example scale                        # 2D 10k, 40k; 3D 10k
//! cargo run --release --example scale -- 2:10000,40000,160000 3:10000,30000 \
//!     --backends direct,multigrid,jacobi --threads 1,2 --steps 2 --chart docs/scale
//! cargo run --release --features petsc --example scale -- 2:40000 \
//!     --backends direct,multigrid,jacobi,petsc-gamg,petsc-hypre --threads 1
//! ```
//!
//! `multigrid` uses the default smoother (Chebyshev of degree 2), `multigrid-gs` Gauss–Seidel.
//! `petsc-gamg` and `petsc-hypre` (builds with the feature `petsc`) are PETSc's CG with its
//! smoothed-aggregation multigrid (GAMG, given the rigid-body modes) and with hypre's
//! BoomerAMG, at the built-in solvers' relative tolerance 1e-10.
//!
//! `DIM:POINTS,..` chooses the blocks (the point count is rounded to whole cells); every
//! (size, backend, threads) combination runs `--repeat N` times (default 1), and each stage's
//! figure is its minimum over the repetitions (the machine's load varies). Per run: seconds per load step per stage,
//! Newton iterations, the peak resident memory of the run (`VmHWM` after resetting it, see
//! `impm::study::memory`) in bytes per point, and the largest items of memory per point as
//! counted from the data structures. Then the exponent p of time ∝ points^p per stage,
//! fitted by least squares in log-log over the sizes, per backend and thread count, and the
//! 2-thread speed-up per stage. With `--chart STEM` it draws seconds per step against points
//! (log-log), per stage, for each backend on the largest thread count.
//!
//! With `--heap` every run also prints where its heap goes: a counting global allocator
//! ([`heap`]) gives the bytes live on the heap and their peak between marks, which systems at
//! the method's hooks set at the end of each stage (connectivity, DOFs and loads, stress
//! update, assembly, linear solve, point update, output, grid reset); and the live heap after
//! the run is split by structure (points' components, supports, tangent, grid fields, the
//! solver's hierarchy as the live heap it added at the step's first solve).
//!
//! With `--bandwidth` it first measures the STREAM triad a = b + s·c (1 and 2 threads, arrays
//! far larger than the caches, [`triad`]) and prints, per run, the bytes each point moves per
//! pass of the stress update and of the assembly, counted from the data structures
//! ([`traffic`]), the GB/s they achieve and their share of the triad's.
//!
//! Results are recorded in docs/performance.md (with the machine's load at the time).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use impm::resources::{Newton, Stage};
use impm::run::{Simulation, load_scene};
use impm::scene::{LinearBackend, Preconditioning};
use impm::solver::Smoother;
use impm::study::memory;
use impm::study::{Series, chart};

/// A counting global allocator: the bytes live on the heap and their peak since the last mark.
/// (A tiny wrapper rather than a crate: `stats_alloc` counts totals allocated and freed but keeps
/// no peak, and `dhat` records a backtrace per allocation, too slow for 1M points.)
mod heap {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

    pub struct Counting;

    static LIVE: AtomicUsize = AtomicUsize::new(0);
    static PEAK: AtomicUsize = AtomicUsize::new(0);

    fn grown(bytes: usize) {
        let now = LIVE.fetch_add(bytes, Relaxed) + bytes;
        PEAK.fetch_max(now, Relaxed);
    }

    // SAFETY: every call is passed on to `System` unchanged; only counters are added.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc(layout) };
            if !p.is_null() {
                grown(layout.size());
            }
            p
        }
        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc_zeroed(layout) };
            if !p.is_null() {
                grown(layout.size());
            }
            p
        }
        unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
            unsafe { System.dealloc(p, layout) };
            LIVE.fetch_sub(layout.size(), Relaxed);
        }
        unsafe fn realloc(&self, p: *mut u8, layout: Layout, size: usize) -> *mut u8 {
            let q = unsafe { System.realloc(p, layout, size) };
            if !q.is_null() {
                LIVE.fetch_sub(layout.size(), Relaxed);
                grown(size);
            }
            q
        }
    }

    /// Bytes live on the heap now.
    pub fn live() -> usize {
        LIVE.load(Relaxed)
    }

    /// The peak since the last call (or the start), and restarts it from the live bytes.
    pub fn take_peak() -> usize {
        PEAK.swap(live(), Relaxed)
    }

    /// One mark: the stage that just ended, the bytes live at its end and their peak during it.
    #[derive(Clone, Copy)]
    pub struct Mark {
        pub stage: &'static str,
        pub live: usize,
        pub peak: usize,
    }

    static MARKS: Mutex<Vec<Mark>> = Mutex::new(Vec::new());

    /// Ends `stage`: records its mark.
    pub fn mark(stage: &'static str) {
        let peak = take_peak();
        let mark = Mark {
            stage,
            live: live(),
            peak,
        };
        MARKS.lock().unwrap_or_else(|e| e.into_inner()).push(mark);
    }

    /// The marks since the last call.
    pub fn take_marks() -> Vec<Mark> {
        std::mem::take(&mut *MARKS.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

#[global_allocator]
static ALLOCATOR: heap::Counting = heap::Counting;

/// Marks the end of each stage for [`heap`] (systems at the method's hooks; they touch no data
/// of the world, so they order against nothing).
struct HeapMarks;

impl impm::plugin::Plugin for HeapMarks {
    fn build<const D: usize>(&self, simulation: &mut impm::plugin::Extension<'_, D>) {
        use impm::plugin::Hook;
        for (hook, stage) in [
            (Hook::Connectivity, "connectivity"),
            (Hook::Loads, "dofs, loads"),
            (Hook::Kinematics, "linear solve"),
            (Hook::BeforeAssembly, "stress update"),
            (Hook::Combine, "assembly"),
            (Hook::PointUpdate, "update points"),
            (Hook::Output, "output"),
        ] {
            simulation.add_systems(hook, move || heap::mark(stage));
        }
    }
}

/// The scene: a square (cube) block of side 1 under its own weight.
fn scene_text(dim: usize) -> String {
    let (zeros, ones, cells, vertical) = match dim {
        2 => (
            "[0.0, 0.0]",
            "[1.0, 1.0]",
            "[cells, cells]",
            "[0.0, body_force]",
        ),
        _ => (
            "[0.0, 0.0, 0.0]",
            "[1.0, 1.0, 1.0]",
            "[cells, cells, cells]",
            "[0.0, 0.0, body_force]",
        ),
    };
    let up = dim - 1;
    let sides = if dim == 2 {
        "fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);".to_string()
    } else {
        "fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\nfix(|x| x[1] == 0.0 || x[1] == 1.0, [1]);"
            .to_string()
    };
    format!(
        "let cells = 10;\nlet steps = 2;\nlet body_force = -10000.0;\n\
         const soil = material(#{{ name: \"block\", E: 1.0e6, nu: 0.3, density: 1.0 }});\n\
         grid(#{{ lower: {zeros}, upper: {ones}, cells: {cells}, basis: \"bspline\", order: 2 }});\n\
         body(#{{ name: \"block\", material: soil, region: box({zeros}, {ones}), ppc: 2 }});\n\
         body_force({vertical});\n\
         fix(|x| x[{up}] == 0.0, [{up}]);\n{sides}\n\
         load_steps(steps);\n\
         analytic_column(#{{ axis: {up}, height: 1.0, material: soil, body_force: body_force }});\n"
    )
}

/// One run's figures.
#[derive(Clone)]
struct Figures {
    points: usize,
    dofs: usize,
    iterations: usize,
    /// Seconds per load step, per stage (`Stage::ALL` order).
    stages: Vec<f64>,
    wall: f64,
    error: Option<f64>,
    peak_mib: Option<f64>,
    baseline_mib: Option<f64>,
    /// Bytes per point counted from the data: (item, bytes per point).
    items: Vec<(&'static str, f64)>,
    /// The speed-up of a perfectly parallel loop on this run's threads against one thread,
    /// measured just before the run: what the machine's load allowed at the time.
    ceiling: f64,
    /// Bytes each point moves per Newton iteration in the stress update and the assembly
    /// (the model of [`traffic`]).
    traffic: [f64; 2],
}

struct Plan {
    blocks: Vec<(usize, Vec<usize>)>,
    backends: Vec<Backend>,
    threads: Vec<usize>,
    steps: usize,
    /// Runs of each combination; each stage's figure is the minimum over them (load noise).
    repeat: usize,
    chart: Option<PathBuf>,
    /// Print where each run's heap goes (`--heap`).
    heap: bool,
    /// The STREAM-like triad's GB/s per thread count (`--bandwidth`), measured at the start.
    triad: Vec<(usize, f64)>,
}

fn parse() -> Result<Plan, String> {
    let mut plan = Plan {
        blocks: Vec::new(),
        backends: vec![Backend::builtin(LinearBackend::Direct, "direct"), MULTIGRID],
        threads: vec![1, 2],
        steps: 2,
        repeat: 1,
        chart: None,
        heap: false,
        triad: Vec::new(),
    };
    let mut bandwidth = false;
    let list = |s: &str| -> Result<Vec<usize>, String> {
        s.split(',')
            .map(|v| v.trim().parse().map_err(|_| format!("not a number: '{v}'")))
            .collect()
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--backends" => {
                plan.backends = value()?
                    .split(',')
                    .map(|b| match b {
                        "direct" => Ok(Backend::builtin(LinearBackend::Direct, "direct")),
                        "iterative" | "multigrid" => Ok(MULTIGRID),
                        "multigrid-gs" => Ok(MULTIGRID_GS),
                        "jacobi" => Ok(Backend::builtin(
                            LinearBackend::Iterative(Preconditioning::Jacobi),
                            "cg+jacobi",
                        )),
                        "petsc-gamg" | "petsc-hypre" if !cfg!(feature = "petsc") => {
                            Err(format!("backend '{b}': {}", impm::scene::WITHOUT_PETSC))
                        }
                        "petsc-gamg" => Ok(Backend {
                            linear: LinearBackend::Petsc,
                            petsc_options: "-ksp_type cg -pc_type gamg",
                            name: "petsc cg+gamg",
                        }),
                        "petsc-hypre" => Ok(Backend {
                            linear: LinearBackend::Petsc,
                            petsc_options: "-ksp_type cg -pc_type hypre",
                            name: "petsc cg+boomeramg",
                        }),
                        _ => Err(format!(
                            "backend '{b}': direct, multigrid (= iterative), multigrid-gs, \
                             jacobi, petsc-gamg or petsc-hypre"
                        )),
                    })
                    .collect::<Result<_, _>>()?
            }
            "--threads" => plan.threads = list(&value()?)?,
            "--steps" => plan.steps = value()?.parse().map_err(|_| "--steps N".to_string())?,
            "--repeat" => {
                plan.repeat = value()?.parse().map_err(|_| "--repeat N".to_string())?;
                plan.repeat = plan.repeat.max(1);
            }
            "--chart" => plan.chart = Some(PathBuf::from(value()?)),
            "--heap" => plan.heap = true,
            "--bandwidth" => bandwidth = true,
            block => {
                let (dim, sizes) = block.split_once(':').ok_or(format!(
                    "'{block}': expected DIM:POINTS,.. (e.g. 2:10000,40000)"
                ))?;
                let dim: usize = dim.parse().map_err(|_| format!("dimension '{dim}'"))?;
                if !(2..=3).contains(&dim) {
                    return Err(format!("dimension {dim}: 2 or 3"));
                }
                plan.blocks.push((dim, list(sizes)?));
            }
        }
    }
    if plan.blocks.is_empty() {
        plan.blocks = vec![(2, vec![10_000, 40_000]), (3, vec![10_000])];
    }
    if bandwidth {
        plan.triad = [1, 2].map(|t| (t, triad(t))).to_vec();
    }
    Ok(plan)
}

fn run<const D: usize>(
    scene: &Path,
    cells: usize,
    steps: usize,
    backend: Backend,
    threads: usize,
    show_heap: bool,
) -> Figures {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let ceiling = ceiling(threads);
    pool.install(|| {
        let set = [
            ("cells".to_string(), cells.to_string()),
            ("steps".to_string(), steps.to_string()),
        ];
        let mut spec = load_scene(scene, &set).unwrap_or_else(|e| panic!("{e}"));
        spec.solver.linear = backend.linear;
        spec.solver.petsc_options = backend.petsc_options.to_string();
        let out = std::env::temp_dir().join(format!("impm-scale-{}", std::process::id()));
        let started = memory::begin_run();
        let mut sim = Simulation::<D>::new(&spec, &out).unwrap_or_else(|e| panic!("{e}"));
        // The points are spawned: their seeds in the scene are no longer needed.
        drop(spec);
        if show_heap {
            sim.add_plugin(&HeapMarks).unwrap_or_else(|e| panic!("{e}"));
        }
        let before = heap::live();
        heap::take_peak();
        heap::take_marks();
        sim.run(|_| heap::mark("grid reset"))
            .unwrap_or_else(|e| panic!("{e}"));
        let items = memory_items(&mut sim);
        let traffic = traffic(&mut sim);
        if show_heap {
            print_heap(
                &mut sim,
                before,
                &heap::take_marks(),
                &memory::end_run(started),
            );
        }
        let used = memory::end_run(started);
        let _ = std::fs::remove_dir_all(&out);
        let summary = &sim.summary;
        let (stages, wall) = summary.total_seconds();
        let n = summary.steps.len() as f64;
        Figures {
            points: summary.points,
            dofs: summary.steps.last().map_or(0, |s| s.dofs),
            iterations: summary.total_iterations(),
            stages: stages.seconds.iter().map(|s| s.as_secs_f64() / n).collect(),
            wall: wall / n,
            error: summary.final_error(),
            peak_mib: used.peak_mib,
            baseline_mib: used.baseline_mib,
            items,
            ceiling,
            traffic,
        }
    })
}

/// Where the run's heap went (`--heap`): per stage, the bytes live at its end and their peak
/// during it (the largest over steps and Newton iterations), and the live heap after the run
/// split by structure; all in bytes per point.
fn print_heap<const D: usize>(
    sim: &mut Simulation<D>,
    before: usize,
    marks: &[heap::Mark],
    used: &memory::MemoryUse,
) {
    use impm::basis::NodeWeight;
    use impm::components::Support;
    use impm::resources::GridFields;
    let points = sim.summary.points.max(1) as f64;
    let per_point = |bytes: usize| format!("{:.0}", bytes as f64 / points);
    let cache = sim.world.resource::<impm::stages::ColouringCache>();
    let (stages, _) = sim.summary.total_seconds();
    let assembly = stages.get(Stage::Assembly).as_secs_f64();
    println!(
        "  colouring: made {} times, reused {} times, {:.3} s in all ({:.1} % of the assembly's \
         {:.3} s; {:.3} s per colouring)",
        cache.computed,
        cache.reused,
        cache.seconds.as_secs_f64(),
        100.0 * cache.seconds.as_secs_f64() / assembly.max(1e-12),
        assembly,
        cache.seconds.as_secs_f64() / cache.computed.max(1) as f64
    );
    println!(
        "  heap of {} points: {} B/point live before the first step",
        sim.summary.points,
        per_point(before)
    );
    println!("  | stage (end) | live at its end, B/point | peak during it, B/point |");
    println!("  |---|---|---|");
    let mut stages: Vec<(&str, usize, usize)> = Vec::new();
    for mark in marks {
        match stages.iter_mut().find(|(s, ..)| *s == mark.stage) {
            Some(entry) => (entry.1, entry.2) = (entry.1.max(mark.live), entry.2.max(mark.peak)),
            None => stages.push((mark.stage, mark.live, mark.peak)),
        }
    }
    for (stage, live, peak) in &stages {
        println!(
            "  | {stage} | {} | {} |",
            per_point(*live),
            per_point(*peak)
        );
    }
    let peak = marks.iter().map(|m| m.peak).max().unwrap_or(0);
    let resident = used.peak_mib.map_or(0.0, |m| m * 1048576.0);
    println!(
        "  peak heap {} B/point; peak resident {:.0} B/point (the rest: the binary, \
         allocator slack, pages freed but kept)",
        per_point(peak),
        resident / points
    );
    // The solver's own heap: what the step's first linear solve left live.
    let first_solve = marks
        .windows(2)
        .find(|w| w[0].stage == "assembly" && w[1].stage == "linear solve")
        .map_or(0, |w| w[1].live.saturating_sub(w[0].live));
    // Live after the run, by structure.
    let live = heap::live();
    // The ECS tables: per row (entity slot) the entity, and per component its value and its
    // two change ticks; slots are allocated to the table's capacity, empty or not.
    let mut inline = 0usize;
    let mut tables = std::collections::BTreeSet::new();
    for archetype in sim.world.archetypes().iter() {
        if !tables.insert(archetype.table_id().as_usize()) {
            continue;
        }
        let Some(table) = sim.world.storages().tables.get(archetype.table_id()) else {
            continue;
        };
        let row: usize = archetype
            .table_components()
            .filter_map(|id| sim.world.components().get_info(id))
            .map(|info| info.layout().size() + 8)
            .sum();
        let entity = std::mem::size_of::<bevy_ecs::entity::Entity>();
        inline += (row + entity) * table.entity_capacity();
    }
    let support: usize = sim
        .world
        .query::<&Support<D>>()
        .iter(&sim.world)
        .map(|s| s.0.capacity() * std::mem::size_of::<NodeWeight<D>>())
        .sum();
    let matrix = &sim.world.resource::<Newton>().matrix;
    let tangent = matrix.nonzeros() * 16 + (matrix.size() + 1) * 8;
    let fields = sim.world.resource::<GridFields<D>>();
    let grid = fields.node_storage_bytes();
    let counted = inline + support + tangent + grid + first_solve;
    println!(
        "  live after the run {} B/point: ECS tables {} (components inline, points and grid \
         nodes, empty slots included), supports {}, tangent (values, row indices, column starts) {}, grid fields \
         {}, solver (left live by the first solve) {}, the rest {}",
        per_point(live),
        per_point(inline),
        per_point(support),
        per_point(tangent),
        per_point(grid),
        per_point(first_solve),
        per_point(live.saturating_sub(counted))
    );
}

/// The largest items of memory per point, counted from the data structures after the run.
fn memory_items<const D: usize>(sim: &mut Simulation<D>) -> Vec<(&'static str, f64)> {
    use impm::basis::NodeWeight;
    use impm::components::{Support, Trial};
    let points = sim.summary.points.max(1) as f64;
    let mut support = 0usize;
    for s in sim.world.query::<&Support<D>>().iter(&sim.world) {
        support += s.0.capacity() * std::mem::size_of::<NodeWeight<D>>()
            + std::mem::size_of::<Support<D>>();
    }
    let trial = std::mem::size_of::<Trial<D>>() as f64;
    let matrix = &sim.world.resource::<Newton>().matrix;
    // values (f64) and row indices (usize) per stored entry; column pointers are per DOF.
    let tangent = (matrix.nonzeros() * 16 + matrix.size() * 8) as f64;
    vec![
        ("support (weights, gradients)", support as f64 / points),
        ("trial state", trial),
        ("tangent (values, pattern)", tangent / points),
    ]
}

/// Per run, for the stress update and the assembly: the bytes a point moves per Newton
/// iteration ([`traffic`]), the GB/s achieved (bytes × points × passes / stage seconds, a pass
/// per Newton iteration and one at the converged iterate)
/// and its ratio to the triad's GB/s on the same thread count (`--bandwidth`).
fn bandwidth(plan: &Plan, results: &BTreeMap<(usize, String, usize), Vec<Figures>>) {
    println!(
        "\nbytes per point per Newton iteration (counted from the data) against the STREAM triad: {}",
        plan.triad
            .iter()
            .map(|(t, gbs)| format!("{t} thread(s) {gbs:.2} GB/s"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "| dim | points | backend | threads | stage | B per point per pass | s per pass | GB/s | of triad |"
    );
    println!("|{}", "---|".repeat(9));
    for ((dim, backend, threads), runs) in results {
        let Some(&(_, triad)) = plan.triad.iter().find(|(t, _)| t == threads) else {
            continue;
        };
        for f in runs {
            // One stress update and assembly per linear solve, and one more at the converged
            // iterate (its residual is checked).
            let passes = f.iterations as f64 / plan.steps as f64 + 1.0;
            for (k, stage) in [Stage::StressUpdate, Stage::Assembly]
                .into_iter()
                .enumerate()
            {
                let seconds = f.stages[stage_index(stage)] / passes;
                let gbs = f.traffic[k] * f.points as f64 / seconds.max(1e-12) / 1e9;
                println!(
                    "| {dim} | {} | {backend} | {threads} | {} | {:.0} | {seconds:.3} | {gbs:.2} | {:.0} % |",
                    f.points,
                    stage.name(),
                    f.traffic[k],
                    100.0 * gbs / triad,
                );
            }
        }
    }
}

/// The bytes a point moves per Newton iteration in the stress update and in the assembly,
/// counted from the data structures (`size_of`, the supports' lengths), each byte read or
/// written once (no write-allocate, no cache reuse across points except where stated):
///
/// - stress update: its support (n `NodeWeight`s: node, weight, gradient, and the `Vec`
///   header), F (D² f64), the n nodes' increments Δu_i (n·D f64, gathered), its `Trial`
///   written (F, Δf⁻¹, J, b, τ, the tangent c);
/// - assembly: its support, its `Trial` and V0 read; the force on its n nodes read and
///   written (2·n·D f64); the tangent values of its group (the points of one cell share one
///   support and scatter their summed blocks once): the group's n²·D² values read and
///   written (16 B each) and one row index per block column found (n²·D `usize`), divided
///   by the group's points.
///
/// The node-indexed reads (increments, forces, tangent values) are scattered; neighbouring
/// cells share most of them, so caches can serve part of them: the model is what the kernel
/// touches, not what must come from memory.
fn traffic<const D: usize>(sim: &mut Simulation<D>) -> [f64; 2] {
    use impm::basis::NodeWeight;
    use impm::components::{DeformationGradient, ReferenceVolume, Support, Trial};
    use std::mem::size_of;
    let f64s = size_of::<f64>() as f64;
    let (mut points, mut weights, mut scattered) = (0usize, 0usize, 0.0f64);
    let mut group: Option<(usize, usize)> = None;
    for s in sim.world.query::<&Support<D>>().iter(&sim.world) {
        let n = s.0.len();
        points += 1;
        weights += n;
        // A new group where the support differs (first node, length) from the last point's.
        let key = (s.0.first().map_or(usize::MAX, |w| w.node), n);
        if group != Some(key) {
            group = Some(key);
            scattered +=
                (n * n * D * D) as f64 * 2.0 * f64s + (n * n * D * size_of::<usize>()) as f64;
        }
    }
    let points = points.max(1) as f64;
    let n = weights as f64 / points;
    let support = n * size_of::<NodeWeight<D>>() as f64 + size_of::<Support<D>>() as f64;
    let trial = size_of::<Trial<D>>() as f64;
    let stress = support + size_of::<DeformationGradient<D>>() as f64 + n * D as f64 * f64s + trial;
    let assembly = support
        + trial
        + size_of::<ReferenceVolume>() as f64
        + 2.0 * n * D as f64 * f64s
        + scattered / points;
    [stress, assembly]
}

/// The STREAM triad a = b + s·c on `threads` threads over arrays of 2^24 f64 (128 MiB each,
/// far larger than any cache), best of 5: GB/s, counting 24 bytes per element (two reads, one
/// write; the write-allocate read is not counted, as STREAM does not).
fn triad(threads: usize) -> f64 {
    use rayon::prelude::*;
    const N: usize = 1 << 24;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let b = vec![1.0f64; N];
    let c = vec![2.0f64; N];
    let mut a = vec![0.0f64; N];
    let chunk = N / threads;
    let mut best = f64::INFINITY;
    for repeat in 0..5 {
        let s = 3.0 + repeat as f64;
        let start = std::time::Instant::now();
        pool.install(|| {
            a.par_chunks_mut(chunk)
                .zip(b.par_chunks(chunk).zip(c.par_chunks(chunk)))
                .for_each(|(a, (b, c))| {
                    for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
                        *a = b + s * c;
                    }
                });
        });
        best = best.min(start.elapsed().as_secs_f64());
        std::hint::black_box(&a);
    }
    (3 * N * size_of::<f64>()) as f64 / best / 1e9
}

/// The speed-up of a loop without memory traffic or synchronisation (square roots, summed)
/// on `threads` threads against one, now: on a machine shared with other work, no stage can
/// gain more than this.
fn ceiling(threads: usize) -> f64 {
    use rayon::prelude::*;
    const N: u64 = 40_000_000;
    let work = |range: std::ops::Range<u64>| range.map(|i| (i as f64).sqrt()).sum::<f64>();
    let timed = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        let start = std::time::Instant::now();
        let parts = threads as u64;
        let sum: f64 = pool.install(|| {
            (0..parts)
                .into_par_iter()
                .map(|p| work(p * N / parts..(p + 1) * N / parts))
                .sum()
        });
        std::hint::black_box(sum);
        start.elapsed().as_secs_f64()
    };
    if threads == 1 {
        return 1.0;
    }
    timed(1) / timed(threads)
}

/// Two runs of the same problem: each stage's and the step's shortest time, the larger peak.
fn fastest(a: Figures, b: Figures) -> Figures {
    Figures {
        stages: a
            .stages
            .iter()
            .zip(&b.stages)
            .map(|(x, y)| x.min(*y))
            .collect(),
        wall: a.wall.min(b.wall),
        ceiling: a.ceiling.max(b.ceiling),
        peak_mib: a.peak_mib.into_iter().chain(b.peak_mib).reduce(f64::max),
        ..a
    }
}

/// Least-squares slope of log y against log x.
fn exponent(samples: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = samples
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = logs
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = logs.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    (sxx > 0.0).then(|| sxy / sxx)
}

/// A linear-solver backend as the scene's `solver(...)` chooses it, with its name in the tables.
#[derive(Clone, Copy)]
struct Backend {
    linear: LinearBackend,
    /// `petsc_options` (PETSc's backend only).
    petsc_options: &'static str,
    name: &'static str,
}

impl Backend {
    const fn builtin(linear: LinearBackend, name: &'static str) -> Self {
        Self {
            linear,
            petsc_options: "",
            name,
        }
    }
}

const MULTIGRID: Backend = Backend::builtin(
    LinearBackend::Iterative(Preconditioning::Multigrid(Smoother::Chebyshev(2))),
    "cg+multigrid",
);

/// Multigrid with the Gauss–Seidel smoother (the default before 2026-11-24).
const MULTIGRID_GS: Backend = Backend::builtin(
    LinearBackend::Iterative(Preconditioning::Multigrid(Smoother::GaussSeidel)),
    "cg+multigrid(gs)",
);

fn backend_name(b: Backend) -> String {
    b.name.into()
}

/// The stages shown (the others cost less than a percent here).
const SHOWN: [Stage; 6] = [
    Stage::Connectivity,
    Stage::StressUpdate,
    Stage::Assembly,
    Stage::LinearSolve,
    Stage::UpdatePoints,
    Stage::Output,
];

fn stage_index(stage: Stage) -> usize {
    Stage::ALL.iter().position(|s| *s == stage).unwrap()
}

fn main() {
    let plan = parse().unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(2)
    });
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "scale: self-weight block, B-spline q = 2, 2 points per cell per axis, {} load steps; \
         load average at start: {}",
        plan.steps,
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    let dir = std::env::temp_dir().join(format!("impm-scale-scenes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary folder");
    // (dim, backend, threads) -> runs in size order
    let mut results: BTreeMap<(usize, String, usize), Vec<Figures>> = BTreeMap::new();
    println!(
        "| dim | points | DOFs | backend | threads | Newton its | {} | s per step | eq. 15 error | peak MiB | B per point |",
        SHOWN
            .iter()
            .map(|s| s.name())
            .collect::<Vec<_>>()
            .join(" | ")
    );
    println!("|{}", "---|".repeat(11 + SHOWN.len()));
    for (dim, sizes) in &plan.blocks {
        let scene = dir.join(format!("block_{dim}d.rhai"));
        std::fs::write(&scene, scene_text(*dim)).expect("scene file");
        for &points in sizes {
            let per_cell = 1usize << dim;
            let cells = ((points / per_cell) as f64).powf(1.0 / *dim as f64).round() as usize;
            let cells = cells.max(2);
            for &backend in &plan.backends {
                for &threads in &plan.threads {
                    let f = (0..plan.repeat)
                        .map(|_| match dim {
                            2 => run::<2>(&scene, cells, plan.steps, backend, threads, plan.heap),
                            _ => run::<3>(&scene, cells, plan.steps, backend, threads, plan.heap),
                        })
                        .reduce(fastest)
                        .expect("at least one run");
                    let peak_bytes = f.peak_mib.map(|m| m * 1048576.0);
                    println!(
                        "| {dim} | {} | {} | {} | {threads} | {} | {} | {:.3} | {} | {} | {} |",
                        f.points,
                        f.dofs,
                        backend_name(backend),
                        f.iterations,
                        SHOWN
                            .iter()
                            .map(|s| format!("{:.3}", f.stages[stage_index(*s)]))
                            .collect::<Vec<_>>()
                            .join(" | "),
                        f.wall,
                        f.error.map_or("-".into(), |e| format!("{e:.2e}")),
                        f.peak_mib.map_or("-".into(), |m| format!("{m:.0}")),
                        peak_bytes.map_or("-".into(), |b| format!("{:.0}", b / f.points as f64)),
                    );
                    results
                        .entry((*dim, backend_name(backend), threads))
                        .or_default()
                        .push(f);
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    report(&plan, &results);
}

fn report(plan: &Plan, results: &BTreeMap<(usize, String, usize), Vec<Figures>>) {
    if !plan.triad.is_empty() {
        bandwidth(plan, results);
    }
    println!("\nexponent p of seconds per step ∝ points^p (least squares, log-log):");
    println!(
        "| dim | backend | threads | {} | whole step |",
        SHOWN
            .iter()
            .map(|s| s.name())
            .collect::<Vec<_>>()
            .join(" | ")
    );
    println!("|{}", "---|".repeat(4 + SHOWN.len()));
    for ((dim, backend, threads), runs) in results {
        let fit = |y: &dyn Fn(&Figures) -> f64| {
            let samples: Vec<(f64, f64)> = runs.iter().map(|f| (f.points as f64, y(f))).collect();
            exponent(&samples).map_or("-".into(), |p| format!("{p:.2}"))
        };
        println!(
            "| {dim} | {backend} | {threads} | {} | {} |",
            SHOWN
                .iter()
                .map(|s| fit(&|f: &Figures| f.stages[stage_index(*s)]))
                .collect::<Vec<_>>()
                .join(" | "),
            fit(&|f: &Figures| f.wall)
        );
    }
    if let (Some(&one), Some(&many)) = (plan.threads.first(), plan.threads.last())
        && many != one
    {
        println!(
            "\nspeed-up with {many} threads against {one} (same process, same sizes; ceiling: \
             a perfectly parallel loop's speed-up measured just before the {many}-thread run):"
        );
        println!(
            "| dim | points | backend | {} | whole step | ceiling |",
            SHOWN
                .iter()
                .map(|s| s.name())
                .collect::<Vec<_>>()
                .join(" | ")
        );
        println!("|{}", "---|".repeat(5 + SHOWN.len()));
        for ((dim, backend, threads), runs) in results {
            if *threads != one {
                continue;
            }
            let Some(other) = results.get(&(*dim, backend.clone(), many)) else {
                continue;
            };
            for (a, b) in runs.iter().zip(other) {
                println!(
                    "| {dim} | {} | {backend} | {} | {:.2}x | {:.2}x |",
                    a.points,
                    SHOWN
                        .iter()
                        .map(|s| {
                            let i = stage_index(*s);
                            format!("{:.2}x", a.stages[i] / b.stages[i])
                        })
                        .collect::<Vec<_>>()
                        .join(" | "),
                    a.wall / b.wall,
                    b.ceiling
                );
            }
        }
    }
    println!("\nmemory per point, counted from the data (largest run of each block):");
    for ((dim, backend, threads), runs) in results {
        if let Some(f) = runs.last() {
            let counted: Vec<String> = f
                .items
                .iter()
                .map(|(name, bytes)| format!("{name} {bytes:.0} B"))
                .collect();
            let held = match (f.peak_mib, f.baseline_mib) {
                (Some(p), Some(b)) => format!(
                    "peak {:.0} B/point ({:.0} B/point above the baseline)",
                    p * 1048576.0 / f.points as f64,
                    (p - b) * 1048576.0 / f.points as f64
                ),
                _ => "peak not measured".into(),
            };
            println!(
                "  {dim}D {} points, {backend}, {threads} threads: {held}; {}",
                f.points,
                counted.join(", ")
            );
        }
    }
    if let Some(stem) = &plan.chart {
        draw(plan, results, stem);
    }
}

fn draw(plan: &Plan, results: &BTreeMap<(usize, String, usize), Vec<Figures>>, stem: &Path) {
    let threads = *plan.threads.last().unwrap_or(&1);
    for (dim, _) in &plan.blocks {
        let mut series = Vec::new();
        for (b, backend) in plan.backends.iter().enumerate() {
            let Some(runs) = results.get(&(*dim, backend_name(*backend), threads)) else {
                continue;
            };
            for (k, stage) in SHOWN.iter().enumerate() {
                series.push(Series {
                    label: format!("{} {}", stage.name(), backend_name(*backend)),
                    points: runs
                        .iter()
                        .map(|f| (f.points as f64, f.stages[stage_index(*stage)]))
                        .collect(),
                    color: k,
                    dashed: b > 0,
                    markers: true,
                    line: true,
                });
            }
        }
        let path = PathBuf::from(format!("{}_{dim}d", stem.display()));
        match chart(
            &series,
            "points",
            "seconds per load step",
            (true, true),
            plotters::prelude::SeriesLabelPosition::UpperLeft,
            &path,
        ) {
            Ok(()) => println!("chart: {}.svg", path.display()),
            Err(e) => eprintln!("chart: {e}"),
        }
    }
}
