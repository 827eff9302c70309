//! Load-step schedules: the load factor at the end of every step, from the forms a scene can
//! give (`load_steps(n)`: k/n; `load_factors([..])`; `load_factors(n, |k| ..)`, resolved by the
//! builder once the script ran; `load_phases([..])`: linear phases).

/// Largest number of load steps a schedule may have.
pub const MAX_STEPS: usize = 10_000_000;

/// `n` equal steps to load factor 1: k / n, k = 1..=n.
pub fn equal_steps(steps: usize) -> Vec<f64> {
    (1..=steps).map(|step| step as f64 / steps as f64).collect()
}

/// Load factors of phases that start at λ = 0 and each go linearly to their `to` in `steps`
/// equal steps.
pub fn phase_factors(phases: &[(f64, usize)]) -> Vec<f64> {
    let mut factors = Vec::new();
    let mut start = 0.0;
    for &(to, steps) in phases {
        factors.extend((1..=steps).map(|k| start + (to - start) * k as f64 / steps as f64));
        start = to;
    }
    factors
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_steps_and_phases() {
        assert_eq!(equal_steps(4), [0.25, 0.5, 0.75, 1.0]);
        assert_eq!(
            phase_factors(&[(1.0, 2), (1.0, 1), (0.0, 2)]),
            [0.5, 1.0, 1.0, 0.5, 0.0]
        );
    }
}
