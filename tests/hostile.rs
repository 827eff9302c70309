//! Hostile input: a corpus of bad scenes and bad command lines, each with the exit status and
//! a fragment of the message it must print. None may panic (exit 101), hang (each case is
//! killed after `LIMIT`) or pass silently. Scenes are small mutations of one 1D column.

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

/// The longest a case may run.
const LIMIT: Duration = Duration::from_secs(20);

/// A small, valid 1D column (10 cells of quadratic splines, 4 load steps).
const BASE: &str = r#"let cells = 10;
let order = 2;
let ppc = 2;
let steps = 4;
let force = -100.0;
grid(#{ lower: [0.0], upper: [10.0], cells: [cells], basis: "bspline", order: order });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "column", material: m, region: box([0.0], [10.0]), ppc: ppc });
body_force([force]);
fix(|x| x[0] == 0.0, [0]);
load_steps(steps);
"#;

/// One case: the scene (if any) is written to `SCENE`; `args` may name `SCENE`, `DIR` (a
/// fresh folder) and the shipped scenes `COLUMN1D`, `COLUMN2D`, `COLUMN3D`.
struct Case {
    name: &'static str,
    scene: Option<Vec<u8>>,
    args: Vec<&'static str>,
    status: i32,
    fragment: &'static str,
}

fn case(
    name: &'static str,
    scene: Option<&str>,
    args: &[&'static str],
    status: i32,
    fragment: &'static str,
) -> Case {
    Case {
        name,
        scene: scene.map(|s| s.as_bytes().to_vec()),
        args: args.to_vec(),
        status,
        fragment,
    }
}

/// `BASE` with `from` replaced by `to` (which must occur).
fn base_with(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "{from}");
    BASE.replacen(from, to, 1)
}

fn check(scene: &str, status: i32, fragment: &'static str, name: &'static str) -> Case {
    Case {
        name,
        scene: Some(scene.as_bytes().to_vec()),
        args: vec!["check", "SCENE"],
        status,
        fragment,
    }
}

fn corpus() -> Vec<Case> {
    let mut cases = vec![
        // runaway scripts end within the limits, with the line and the limit
        check(
            "loop {}\n",
            1,
            "limit on operations",
            "endless loop at top level",
        ),
        check(
            &format!("{BASE}load_factors(3, |k| {{ loop {{}} }});\n")
                .replace("load_steps(steps);\n", ""),
            1,
            "limit on operations",
            "endless loop in a load function",
        ),
        check(
            &base_with("box([0.0], [10.0])", "|x| { loop {} }"),
            1,
            "limit on operations",
            "endless loop in a region predicate",
        ),
        check(
            "let s = \"x\"; loop { s += s; }\n",
            1,
            "--limit string",
            "growing string",
        ),
        check(
            "let a = [1]; loop { a += a; }\n",
            1,
            "--limit array",
            "growing array",
        ),
        // Rhai does not check a map's size when an index assignment adds a key: the map
        // limit is checked where the loop reads its map again (the line of `m[..] = ..`)
        check(
            "let m = #{};\nlet i = 0;\nloop {\n    m[`k${i}`] = i;\n    i += 1;\n}\n",
            1,
            "scene.rhai:4:5: Size of object map grew beyond the limit on its size (a runaway loop?); --limit map=N raises it",
            "map grown key by key",
        ),
        check(
            "let m = #{ inner: #{} };\nlet i = 0;\nloop { m.inner[`k${i}`] = i; i += 1; }\n",
            1,
            "scene.rhai:3:8: Size of object map grew beyond",
            "nested map grown key by key",
        ),
        check(
            "fn grow(m, n) { for i in 0..n { m[`k${i}`] = i; } m }\nlet m = grow(#{}, 100000);\n",
            1,
            "--limit map",
            "map grown key by key in a function",
        ),
        Case {
            name: "map grown key by key under a raised limit",
            scene: Some(
                b"let m = #{};\nfor i in 0..20000 { m[`k${i}`] = i; }\nif m.len() != 20000 { throw \"lost keys\"; }\n"
                    .to_vec(),
            ),
            args: vec!["check", "SCENE", "--limit", "map=20000"],
            status: 1,
            fragment: "the scene has no grid",
        },
        check(
            "let m = #{}; let i = 0; loop { let n = #{}; n[`k${i}`] = i; m += n; i += 1; }\n",
            1,
            "--limit map",
            "map grown by merging",
        ),
        check(
            "fn f(x) { f(x + 1) }\nf(1);\n",
            1,
            "--limit depth",
            "endless recursion",
        ),
        check(
            "import \"/tmp/impm_hostile_outside\" as m;\n",
            1,
            "may import only",
            "import of an absolute path",
        ),
        check(
            "import \"../outside\" as m;\n",
            1,
            "may import only",
            "import out of the folder",
        ),
        check(
            &base_with(
                "let cells = 10;",
                "let cells = 10;\nimport \"helper\" as h;\nlet unused = h::two();",
            ),
            0,
            "is valid",
            "import from the scene's folder",
        ),
        Case {
            name: "array grown one item at a time",
            scene: Some(b"let a = []; loop { a.push(1); }\n".to_vec()),
            args: vec!["check", "SCENE", "--limit", "seconds=2"],
            status: 1,
            fragment: "--limit seconds=N",
        },
        // sizes checked before allocation
        case(
            "order 1e6",
            Some(BASE),
            &["check", "SCENE", "--set", "order=1000000"],
            1,
            "basis order 1000000 is above the limit of 20",
        ),
        case(
            "order 60 in 3D",
            None,
            &["check", "COLUMN3D", "--set", "order=60"],
            1,
            "above the limit",
        ),
        case(
            "ppc 1000 in 2D",
            None,
            &["check", "COLUMN2D", "--set", "ppc=1000"],
            1,
            "seeding positions, above the limit",
        ),
        case(
            "points limit",
            Some(BASE),
            &["check", "SCENE", "--limit", "points=10"],
            1,
            "--limit points=20",
        ),
        case(
            "memory limit",
            Some(BASE),
            &["check", "SCENE", "--limit", "memory=0"],
            1,
            "positive whole number",
        ),
        case(
            "support limit",
            Some(BASE),
            &["check", "SCENE", "--limit", "support=2"],
            1,
            "--limit support=3",
        ),
        case(
            "limit raised",
            Some(BASE),
            &["check", "SCENE", "--set", "order=21", "--limit", "order=21"],
            0,
            "is valid",
        ),
        case(
            "unknown limit",
            Some(BASE),
            &["check", "SCENE", "--limit", "speed=1"],
            1,
            "no such limit",
        ),
        case(
            "limit without value",
            Some(BASE),
            &["check", "SCENE", "--limit", "order"],
            1,
            "NAME=VALUE",
        ),
        // reading the file
        case(
            "missing scene",
            None,
            &["check", "DIR/none.rhai"],
            1,
            "cannot read the scene script",
        ),
        case(
            "folder as scene",
            None,
            &["check", "DIR"],
            1,
            "cannot read the scene script",
        ),
        case(
            "empty scene",
            Some(""),
            &["check", "SCENE"],
            1,
            "the scene has no grid",
        ),
        case(
            "comments only",
            Some("// nothing\n"),
            &["check", "SCENE"],
            1,
            "the scene has no grid",
        ),
        // --set
        case(
            "number out of range",
            Some(BASE),
            &["check", "SCENE", "--set", "force=1e400"],
            1,
            "out of the range of a float",
        ),
        case(
            "--set twice",
            Some(BASE),
            &["check", "SCENE", "--set", "cells=5", "--set", "cells=6"],
            1,
            "given twice (5 and 6)",
        ),
        case(
            "--set twice in run",
            Some(BASE),
            &[
                "run", "SCENE", "--out", "DIR/o", "--set", "cells=5", "--set", "cells=6",
            ],
            1,
            "given twice (5 and 6)",
        ),
        case(
            "--set unknown",
            Some(BASE),
            &["check", "SCENE", "--set", "nope=1"],
            1,
            "no parameter 'nope'",
        ),
        case(
            "--set without =",
            Some(BASE),
            &["check", "SCENE", "--set", "cells"],
            1,
            "--set expects NAME=VALUE",
        ),
        case(
            "--set text for a count",
            Some(BASE),
            &["check", "SCENE", "--set", "cells=abc"],
            1,
            "cells",
        ),
        case(
            "--set zero cells",
            Some(BASE),
            &["check", "SCENE", "--set", "cells=0"],
            1,
            "cells",
        ),
        case(
            "--set negative cells",
            Some(BASE),
            &["check", "SCENE", "--set", "cells=-5"],
            1,
            "cells",
        ),
        case(
            "--set fractional cells",
            Some(BASE),
            &["check", "SCENE", "--set", "cells=1.5"],
            1,
            "cells",
        ),
        case(
            "--set zero steps",
            Some(BASE),
            &["check", "SCENE", "--set", "steps=0"],
            1,
            "load_steps",
        ),
        case(
            "--set zero order",
            Some(BASE),
            &["check", "SCENE", "--set", "order=0"],
            1,
            "order",
        ),
        case(
            "--set NaN force",
            Some(BASE),
            &["check", "SCENE", "--set", "force=NaN"],
            1,
            "body_force",
        ),
        // scene contents
        check(
            &base_with(
                "load_steps(steps);",
                "load_steps(steps);\noutput(#{ steps: [99] });",
            ),
            1,
            "step 99 is beyond the last load step 4",
            "output step beyond the schedule",
        ),
        check(
            &base_with(
                "load_steps(steps);",
                "load_steps(steps);\noutput(#{ steps: [2], every: 2 });",
            ),
            1,
            "not both",
            "output every and steps",
        ),
        check(
            &base_with(
                "const m",
                "grid(#{ lower: [0.0], upper: [1.0], cells: [2], basis: \"linear\" });\nconst m",
            ),
            1,
            "already called",
            "grid twice",
        ),
        check(&base_with("grid(", "// grid("), 1, "no grid", "no grid"),
        check(&base_with("body(", "// body("), 1, "no body", "no body"),
        check(
            &base_with("load_steps(steps);", ""),
            1,
            "no load steps",
            "no load steps",
        ),
        check(
            &base_with("body_force([force]);", "body_force([force];"),
            1,
            "syntax error",
            "syntax error",
        ),
        check(
            &base_with("body_force([force]);", "body_force([forse]);"),
            1,
            "undefined variable 'forse'",
            "undefined variable",
        ),
        check(
            &base_with("E: 1.0e4", "Ee: 1.0e4"),
            1,
            "Ee",
            "misspelt material option",
        ),
        check(
            &base_with("density: 1.0", "density: -1.0"),
            1,
            "density",
            "negative density",
        ),
        check(
            &base_with("basis: \"bspline\"", "basis: \"spline\""),
            1,
            "got \"spline\"",
            "unknown basis",
        ),
        check(
            &base_with("box([0.0], [10.0])", "box([0.0], [20.0])"),
            1,
            "not inside the grid",
            "region outside the grid",
        ),
        check(
            &base_with("box([0.0], [10.0])", "|x| 1"),
            1,
            "must return true or false",
            "predicate returning a number",
        ),
        check(
            &base_with("x[0] == 0.0", "x[0] == 0.3"),
            1,
            "nodes have x[0] in",
            "support selecting no node",
        ),
        check(
            &base_with("let cells = 10;", "let cells = 10;\nconst h = 1 / 4;")
                .replace("x[0] == 0.0", "x[0] == h * 0.0 - 1.0"),
            1,
            "selects no grid node",
            "integer division to zero",
        ),
        check(
            &base_with("let cells = 10;", "let cells = 10;\nconst h = 1 / cells;").replace(
                "body_force([force]);",
                "body_force([force]);\npoint_load(|x| x[0] > 10.0 - h, [1.0]);",
            ),
            1,
            "points have x[0] in [0.25, 9.75]; a coordinate computed as a division of whole numbers",
            "integer division to zero in a point-load predicate",
        ),
        check(
            &BASE
                .replace("[0.0]", "[1.0e16]")
                .replace("[10.0]", "[1.0e16 + 10.0]")
                .replace("x[0] == 0.0", "x[0] == 1.0e16"),
            1,
            "grid line 10 of axis 0 lies at 10000000000000010, where double precision resolves only 2e0",
            "grid at 1e16 (cells not resolved)",
        ),
        check(
            &base_with("body_force([force]);", "body_force([force, 1.0]);"),
            1,
            "components",
            "body force of the wrong dimension",
        ),
        check(
            &base_with("load_steps(steps);", "load_factors([]);"),
            1,
            "load_factors",
            "empty load factors",
        ),
        check(
            &base_with("load_steps(steps);", "load_steps(1000000000);"),
            1,
            "too many",
            "too many load steps",
        ),
        check(
            &base_with("body_force([force]);", "body_forse([force]);"),
            1,
            "function not found",
            "unknown call",
        ),
        check(
            &base_with("body_force([force]);", "body_force();"),
            1,
            "body_force",
            "call without arguments",
        ),
        check(
            &base_with("upper: [10.0]", "upper: [-1.0]"),
            1,
            "must be greater than lower",
            "inverted grid",
        ),
        check(
            &base_with(
                "load_steps(steps);",
                "load_steps(steps);\nthrow \"stop here\";",
            ),
            1,
            "stop here",
            "script throws",
        ),
        check(
            &base_with(
                "let cells = 10;",
                "let cells = 10;\nlet a = [1]; let b = a[5];",
            ),
            1,
            "out of bounds",
            "index out of bounds",
        ),
        // command lines
        case("no arguments", None, &[], 2, "Usage"),
        case(
            "unknown command",
            None,
            &["frobnicate"],
            2,
            "unrecognized subcommand",
        ),
        case("run without scene", None, &["run"], 2, "required"),
        case(
            "unknown flag",
            Some(BASE),
            &["run", "SCENE", "--fast"],
            2,
            "unexpected argument",
        ),
        case(
            "output folder cannot be created",
            Some(BASE),
            &["run", "SCENE", "--out", "/proc/impm/x"],
            1,
            "cannot create the output folder",
        ),
        case(
            "study: unknown parameter",
            Some(BASE),
            &["study", "SCENE", "--sweep", "cels=5,10", "--out", "DIR/s"],
            1,
            "no parameter 'cels'",
        ),
        case(
            "study: sweep without values",
            Some(BASE),
            &["study", "SCENE", "--sweep", "cells", "--out", "DIR/s"],
            1,
            "--sweep expects",
        ),
        case(
            "study: negative timeout",
            Some(BASE),
            &[
                "study",
                "SCENE",
                "--sweep",
                "cells=5",
                "--timeout=-1",
                "--out",
                "DIR/s",
            ],
            1,
            "positive number of seconds",
        ),
        case(
            "study: swept and set",
            Some(BASE),
            &[
                "study", "SCENE", "--sweep", "cells=5", "--set", "cells=6", "--out", "DIR/s",
            ],
            1,
            "given twice",
        ),
        case(
            "study: --set twice",
            Some(BASE),
            &[
                "study", "SCENE", "--sweep", "cells=5", "--set", "force=1", "--set", "force=2",
                "--out", "DIR/s",
            ],
            1,
            "parameter 'force' is given twice (1 and 2",
        ),
        case(
            "study: a word in a numeric sweep",
            Some(BASE),
            &["study", "SCENE", "--sweep", "cells=5,ten", "--out", "DIR/s"],
            1,
            "parameter 'cells' = 'ten' is not a number",
        ),
        case(
            "study: empty value",
            Some(BASE),
            &["study", "SCENE", "--sweep", "cells=5,,6", "--out", "DIR/s"],
            1,
            "non-empty",
        ),
        // piped (no terminal): one line per converged step with its figures
        case(
            "progress when piped",
            Some(BASE),
            &["run", "SCENE", "--out", "DIR/o"],
            0,
            "step 4/4 λ=1.0000 iterations",
        ),
        // a tiny first increment converges (tolerance relative to the load scale)
        case(
            "tiny load increment",
            Some(&base_with(
                "load_steps(steps);",
                "load_factors([1e-6, 1.0]);",
            )),
            &["run", "SCENE", "--out", "DIR/o"],
            0,
            "done: 2 steps",
        ),
        // a warning given mid-run (here: the material leaves its surface condition, cubic
        // splines with 2x2 points per cell) is repeated on the last line, which stays on screen;
        // counted with the one the scene gets before the run (cubic splines integrated at the
        // points: a prescribed surface displacement is not to be trusted to 1 %)
        case(
            "warning repeated at the end",
            Some(
                r#"grid(#{ lower: [0.0, 0.0], upper: [1.0, 1.2], cells: [4, 4], basis: "bspline", order: 3 });
const m = material(#{ name: "soil", E: 1000.0, nu: 0.0, density: 1.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 2 });
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
surface_displace(#{ on: [[0.0, 1.0], [1.0, 1.0]], displacement: [0.0, -0.2], name: "top" });
load_steps(40);
"#,
            ),
            &["run", "SCENE", "--out", "DIR/o"],
            0,
            " s, 2 warnings (above and in summary.json)\nresults: ",
        ),
        // a body with no support is named at the first solve, not after the step cuts
        Case {
            name: "body with no support",
            scene: Some(base_with("fix(|x| x[0] == 0.0, [0]);\n", "").into_bytes()),
            args: vec!["run", "SCENE", "--out", "DIR/o"],
            status: 1,
            fragment: "load step 1: body 'column' is not held: the tangent stiffness is singular, nothing stops it moving along x; add fix(...) or displace(...)",
        },
        // the method cannot be right: say so
        case(
            "too few points for the order",
            None,
            &["check", "COLUMN3D", "--set", "cells=4", "--set", "ppc=2"],
            0,
            "rank deficient",
        ),
    ];
    // a UTF-8 byte-order mark is accepted; invalid UTF-8 is named
    let mut bom = vec![0xef, 0xbb, 0xbf];
    bom.extend_from_slice(BASE.as_bytes());
    cases.push(Case {
        name: "byte-order mark",
        scene: Some(bom),
        args: vec!["check", "SCENE"],
        status: 0,
        fragment: "is valid",
    });
    cases.push(Case {
        name: "not UTF-8",
        scene: Some(vec![b'l', b'e', b't', 0xff, 0xfe, b'\n']),
        args: vec!["check", "SCENE"],
        status: 1,
        fragment: "not UTF-8",
    });
    cases
}

fn shipped(name: &str) -> String {
    common::shipped_scene(name).display().to_string()
}

/// Runs `args` with a time limit; (exit status or None if killed, stdout + stderr).
fn run_limited(args: &[String]) -> (Option<i32>, String, Duration) {
    let start = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_impm"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("impm starts");
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let readers = [
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = stdout.read_to_string(&mut s);
            s
        }),
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = stderr.read_to_string(&mut s);
            s
        }),
    ];
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status.code();
        }
        if start.elapsed() > LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let text: Vec<String> = readers.into_iter().map(|r| r.join().unwrap()).collect();
    (status, text.join("\n"), start.elapsed())
}

#[test]
fn every_bad_scene_and_command_line_ends_quickly_with_its_message() {
    let root = common::temp_dir("hostile", "corpus");
    std::fs::create_dir_all(&root).unwrap();
    std::fs::write("/tmp/impm_hostile_outside.rhai", "let x = 1;\n").unwrap();
    std::fs::write(root.join("outside.rhai"), "let x = 1;\n").unwrap();
    let cases = corpus();
    assert!(cases.len() >= 60, "{} cases", cases.len());
    let mut failures = Vec::new();
    for (k, case) in cases.iter().enumerate() {
        let dir: PathBuf = root.join(format!("case{k:02}"));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("helper.rhai"), "fn two() { 2 }\n").unwrap();
        let scene = dir.join("scene.rhai");
        if let Some(text) = &case.scene {
            std::fs::write(&scene, text).unwrap();
        }
        let args: Vec<String> = case
            .args
            .iter()
            .map(|a| {
                a.replace("SCENE", &scene.display().to_string())
                    .replace("DIR", &dir.display().to_string())
                    .replace("COLUMN1D", &shipped("column_1d.rhai"))
                    .replace("COLUMN2D", &shipped("column_2d.rhai"))
                    .replace("COLUMN3D", &shipped("column_3d.rhai"))
            })
            .collect();
        let (status, text, took) = run_limited(&args);
        let ok = status == Some(case.status)
            && text.contains(case.fragment)
            && !text.contains("panicked");
        if !ok {
            failures.push(format!(
                "{}: expected status {} and {:?}, got {status:?} after {took:.1?}:\n{text}",
                case.name, case.status, case.fragment
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&root);
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n---\n")
    );
}
