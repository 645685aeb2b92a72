//! The warm start: the next solve starts from the last plan shifted by the steps that elapsed,
//! inputs and ALM multipliers alike, or from a plan the caller sets.

use super::Mpc;
use crate::error::{MpcError, invalid_input};

impl Mpc {
    /// Replaces the warm start of the next solve (`N x 3` inputs, clipped to the bounds).
    pub fn set_warm_start(&mut self, u: &[f64]) -> Result<(), MpcError> {
        if u.len() != self.warm.len() {
            return Err(invalid_input(
                "warm_start",
                format!("must hold {} values ({} x 3), got {}", self.warm.len(), self.def.horizon, u.len()),
            ));
        }
        if let Some(k) = u.iter().position(|v| !v.is_finite()) {
            return Err(invalid_input(format!("warm_start[{}][{}]", k / 3, k % 3), "must be finite"));
        }
        for (k, (w, v)) in self.warm.iter_mut().zip(u).enumerate() {
            *w = v.clamp(self.def.bounds.min[k % 3], self.def.bounds.max[k % 3]);
        }
        Ok(())
    }

    /// Replaces the ALM multipliers the next solve starts from (one per constraint value of
    /// the distance formulation: scenario-major, then step, then constraint; see
    /// [`Mpc::multipliers`]). Each must be finite and within `[0, max_multiplier]`.
    pub fn set_warm_multipliers(&mut self, y: &[f64]) -> Result<(), MpcError> {
        if y.len() != self.warm_multipliers.len() {
            return Err(invalid_input(
                "multipliers",
                format!(
                    "must hold {} values (scenarios x steps x constraints per point), got {}",
                    self.warm_multipliers.len(),
                    y.len()
                ),
            ));
        }
        let max = self.settings.max_multiplier;
        if let Some(k) = y.iter().position(|v| !(v.is_finite() && (0.0..=max).contains(v))) {
            return Err(invalid_input(format!("multipliers[{k}]"), format!("must be in [0, {max}]")));
        }
        self.warm_multipliers.copy_from_slice(y);
        Ok(())
    }

    /// Shifts the warm start (inputs and multipliers) by `steps` more steps, the last one
    /// repeated: for a controller whose cycle lasted that many more of its sampling times.
    pub fn advance_warm_start(&mut self, steps: usize) {
        let horizon = self.def.horizon;
        let steps = steps.min(horizon - 1);
        if steps == 0 {
            return;
        }
        let n = self.warm.len();
        self.warm.copy_within(3 * steps.., 0);
        for j in horizon - steps..horizon {
            let last =
                [self.warm[n - 3 * steps - 3], self.warm[n - 3 * steps - 2], self.warm[n - 3 * steps - 1]];
            self.warm[3 * j..3 * j + 3].copy_from_slice(&last);
        }
        let n_con = self.def.constraints_per_point();
        if n_con > 0 && !self.warm_multipliers.is_empty() {
            for i in 0..self.def.num_scenarios() {
                let block = &mut self.warm_multipliers[i * horizon * n_con..(i + 1) * horizon * n_con];
                block.copy_within(steps * n_con.., 0);
                for j in horizon - steps..horizon {
                    let (head, tail) = block.split_at_mut(j * n_con);
                    tail[..n_con]
                        .copy_from_slice(&head[(horizon - steps - 1) * n_con..(horizon - steps) * n_con]);
                }
            }
        }
    }

    /// Forgets the previous solution: the next solve starts from hover.
    pub fn reset_warm_start(&mut self) {
        for j in 0..self.def.horizon {
            self.warm[3 * j..3 * j + 3].copy_from_slice(&self.def.u_ref);
        }
        self.has_solution = false;
        self.penalty = self.settings.initial_penalty;
        self.warm_multipliers.iter_mut().for_each(|y| *y = 0.0);
        self.panoc.forget_lipschitz();
    }

    /// Shifts the last solution by one step into the warm start (last input repeated).
    pub(super) fn shift_solution_into_warm_start(&mut self) {
        self.warm.copy_from_slice(&self.solution);
        self.warm_multipliers.copy_from_slice(&self.multipliers);
        self.advance_warm_start(1);
    }
}

/// `plan` (`N x 3` inputs, flattened) shifted one step into `out`, the last input repeated: the
/// warm start of the cycle after the one that flew `plan`'s first input.
pub fn shift_plan_into(plan: &[f64], out: &mut [f64]) {
    let n = plan.len();
    out[..n - 3].copy_from_slice(&plan[3..]);
    out[n - 3..].copy_from_slice(&plan[n - 3..]);
}

/// [`shift_plan_into`] into a new vector.
pub fn shifted_plan(plan: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; plan.len()];
    shift_plan_into(plan, &mut out);
    out
}
