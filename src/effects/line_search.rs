//! The Newton line search as a scene option: `solver(#{ line_search: true, max_backtracks: 8 })`
//! (the options are the solver's, read by `scene::calls`). The method is in
//! `stages::line_search`; this module gives the run its state and adds the judge of each
//! iterate at `Hook::Convergence`, so a scene without the option schedules nothing of it (the
//! Newton loop's `line_search::begin_step`, `retry_after_failure` and `is_backtracking` find no
//! state and do nothing).

use crate::method::Hook;
use crate::plugin::{Extension, Plugin};
use crate::scene::SceneSpec;
use crate::stages::line_search::{LineSearch, judge_iterate};

/// The module: built when the scene asks for the line search.
#[derive(Clone, Copy, Debug, Default)]
pub struct LineSearchModule;

impl Plugin for LineSearchModule {
    fn name(&self) -> &'static str {
        "line search"
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.solver.line_search
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let merit = simulation.spec().solver.merit;
        simulation.world().insert_resource(LineSearch::new(merit));
        simulation.add_systems(Hook::Convergence, judge_iterate::<D>);
    }
}
