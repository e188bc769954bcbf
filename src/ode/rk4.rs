use super::{Options, Outcome, System};
use std::ops::ControlFlow;

pub(super) fn integrate<const N: usize, S, F>(
    _sys: &S,
    _y0: [f64; N],
    _times: &[f64],
    _opts: &Options,
    _observe: F,
) -> Outcome
where
    S: System<N> + ?Sized,
    F: FnMut(usize, &[f64; N]) -> ControlFlow<()>,
{
    todo!("integrator not yet implemented")
}
