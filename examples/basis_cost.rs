//! What one point's weights cost per method: nanoseconds per point for the connectivity kernel
//! (`GridBasis::eval` for linear and B-splines, `basis::eval_point_domain` for GIMP, CPDI and
//! B-splines averaged over the domain), in 1D, 2D and 3D, on points spread over a grid with a
//! mildly stretched and sheared F, and the ratio to linear MPM in the same process. Results are
//! recorded in docs/performance.md.
//!
//!     cargo run --release --example basis_cost

use std::hint::black_box;
use std::time::Instant;

use impm::basis::{BasisKind, DomainScratch, GimpDomain, GridBasis, NodeWeight, eval_point_domain};
use nalgebra::{SMatrix, SVector};

const POINTS: usize = 200_000;

fn cost<const D: usize>(kind: BasisKind) -> (f64, f64) {
    let grid = GridBasis::<D>::new(&[0.0; D], &[10.0; D], &[10; D], kind).unwrap();
    // points on a quasi-random lattice, away from the boundary by more than a domain
    let points: Vec<SVector<f64, D>> = (0..POINTS)
        .map(|p| {
            SVector::from_fn(|k, _| {
                let golden = [
                    0.618_033_988_749_895,
                    0.754_877_666_246_693,
                    0.569_840_290_998_053,
                ];
                0.5 + 9.0 * ((p as f64 + 0.5) * golden[k]).fract()
            })
        })
        .collect();
    let f = SMatrix::<f64, D, D>::from_fn(|a, b| if a == b { 1.05 } else { 0.02 });
    let half = SVector::<f64, D>::repeat(0.25);
    let mut scratch = DomainScratch::<D>::default();
    let mut out: Vec<NodeWeight<D>> = Vec::new();
    let mut support = 0usize;
    let start = Instant::now();
    for x in &points {
        eval_point_domain(&grid, x, &f, &half, &mut scratch, &mut out).unwrap();
        support += black_box(out.len());
    }
    let seconds = start.elapsed().as_secs_f64();
    (
        1e9 * seconds / POINTS as f64,
        support as f64 / POINTS as f64,
    )
}

fn main() {
    let kinds = [
        ("linear", BasisKind::Linear),
        ("bspline q=2", BasisKind::BSpline { order: 2 }),
        ("bspline q=3", BasisKind::BSpline { order: 3 }),
        ("bspline q=2 dom", BasisKind::BSplineDomain { order: 2 }),
        ("bspline q=3 dom", BasisKind::BSplineDomain { order: 3 }),
        (
            "gimp fixed",
            BasisKind::Gimp {
                domain: GimpDomain::Fixed,
            },
        ),
        (
            "gimp stretched",
            BasisKind::Gimp {
                domain: GimpDomain::Stretched,
            },
        ),
        ("cpdi", BasisKind::Cpdi),
    ];
    println!(
        "{:<16} {:>30} {:>30} {:>30}",
        "basis",
        "1D ns/point (nodes) vs linear",
        "2D ns/point (nodes) vs linear",
        "3D ns/point (nodes) vs linear"
    );
    let mut linear = None;
    for (name, kind) in kinds {
        let costs = [cost::<1>(kind), cost::<2>(kind), cost::<3>(kind)];
        let baseline = *linear.get_or_insert(costs.map(|(t, _)| t));
        print!("{name:<16}");
        for ((t, n), t_linear) in costs.iter().zip(baseline) {
            print!(" {t:>14.1} ({n:>6.2}) {:>6.2}x", t / t_linear);
        }
        println!();
    }
}
