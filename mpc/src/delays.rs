//! Delay statistics of `docs/spec.md`: a fixed-size window of observed round-trip delays, a Gamma
//! distribution fitted to it by moments, and the scenario weights from its CDF.

use statrs::distribution::{ContinuousCDF, Gamma};

/// A Gamma distribution by shape and scale (s).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GammaParams {
    pub shape: f64,
    pub scale_s: f64,
}

impl GammaParams {
    pub fn mean_s(&self) -> f64 {
        self.shape * self.scale_s
    }

    /// Moment fit: `shape = mu^2 / sigma^2`, `scale = sigma^2 / mu`. `None` when the moments
    /// cannot define a Gamma (non-positive mean, non-finite variance, or a variance that is
    /// zero up to rounding: identical delays summed in floating point leave ~1e-34, which
    /// would otherwise become a shape of 1e30).
    pub fn from_moments(mean_s: f64, variance_s2: f64) -> Option<Self> {
        const MIN_RELATIVE_VARIANCE: f64 = 1e-12;
        if !(mean_s.is_finite() && variance_s2.is_finite() && mean_s > 0.0) {
            return None;
        }
        if variance_s2 <= MIN_RELATIVE_VARIANCE * mean_s * mean_s {
            return None;
        }
        let shape = mean_s * mean_s / variance_s2;
        let scale_s = variance_s2 / mean_s;
        (shape.is_finite() && scale_s.is_finite() && shape > 0.0 && scale_s > 0.0)
            .then_some(Self { shape, scale_s })
    }

    /// `P(d <= t)`; `None` if statrs rejects the parameters.
    pub fn cdf(&self, t_s: f64) -> Option<f64> {
        let g = Gamma::new(self.shape, 1.0 / self.scale_s).ok()?;
        Some(g.cdf(t_s.max(0.0)))
    }
}

/// Where the weights of a cycle came from.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum WeightSource {
    /// The run has no delays: the fixed nominal weights.
    Nominal,
    /// Too few observations, or a degenerate window (zero variance, as under a constant
    /// delay, or non-finite moments): the configured prior, as the spec asks.
    Prior(GammaParams),
    /// Fitted to the window.
    Fitted(GammaParams),
}

/// The last `capacity` observed round-trip delays.
#[derive(Debug, Clone)]
pub struct DelayWindow {
    buf: Vec<f64>,
    capacity: usize,
    next: usize,
    len: usize,
}

impl DelayWindow {
    /// A window of `capacity` delays (`n_max`, at least 1).
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self { buf: vec![0.0; capacity], capacity, next: 0, len: 0 }
    }

    /// Records one delay; non-finite or negative values are not delays and are ignored.
    pub fn push(&mut self, delay_s: f64) -> bool {
        if !delay_s.is_finite() || delay_s < 0.0 {
            return false;
        }
        self.buf[self.next] = delay_s;
        self.next = (self.next + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
        true
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn clear(&mut self) {
        self.len = 0;
        self.next = 0;
    }

    /// The longest delay in the window, s (`None` when empty).
    pub fn max_s(&self) -> Option<f64> {
        self.buf[..self.len].iter().copied().reduce(f64::max)
    }

    /// Mean and population variance (the method of moments uses the sample's own moments).
    pub fn moments(&self) -> Option<(f64, f64)> {
        if self.len == 0 {
            return None;
        }
        let values = &self.buf[..self.len];
        let n = self.len as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
        Some((mean, var))
    }

    /// The Gamma fit, or `None` with fewer than `min_samples` delays or degenerate moments.
    pub fn fit(&self, min_samples: usize) -> Option<GammaParams> {
        if self.len < min_samples.max(2) {
            return None;
        }
        let (mean, var) = self.moments()?;
        GammaParams::from_moments(mean, var)
    }
}

/// Least share of a Gamma's probability at or below the longest sampling time for the paper's
/// weights to stand as they are. Below it the link is slower than every scenario (a
/// near-constant 0.5 s delay fits a Gamma whose CDF is 0 at 0.33 s), and the paper's weights
/// would all be zero or nearly so: an objective that no longer weighs the goal.
pub const MIN_MASS_WITHIN_SAMPLING_TIMES: f64 = 1e-3;

/// The paper's weights, `w_1 = G(ts_1)`, `w_i = G(ts_i) - G(ts_{i-1})` (docs/spec.md), into
/// `out` (one per sampling time). Where `G(ts_M)` is below [`MIN_MASS_WITHIN_SAMPLING_TIMES`]
/// the mass beyond the longest sampling time belongs to the last scenario, `w_M = 1 -
/// G(ts_{M-1})`, the one that stands for the longest delays: the weights are then defined for
/// every window a link can produce, and paper mode's stay the paper's wherever they carry
/// weight. Returns `false` (and leaves `out` unspecified) if the CDF cannot be evaluated.
pub fn weights_from_gamma(gamma: &GammaParams, sampling_times_s: &[f64], out: &mut [f64]) -> bool {
    let Ok(g) = Gamma::new(gamma.shape, 1.0 / gamma.scale_s) else {
        return false;
    };
    let mut previous = 0.0;
    for (w, &ts) in out.iter_mut().zip(sampling_times_s) {
        let cdf = g.cdf(ts);
        if !cdf.is_finite() {
            return false;
        }
        *w = (cdf - previous).max(0.0);
        previous = previous.max(cdf);
    }
    let n = out.len().min(sampling_times_s.len());
    if n > 0 && previous < MIN_MASS_WITHIN_SAMPLING_TIMES {
        let before_last: f64 = out[..n - 1].iter().sum();
        out[n - 1] = (1.0 - before_last).max(0.0);
    }
    true
}

/// Settings of the weight estimator.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WeightSettings {
    /// Window size `n_max`.
    pub window: usize,
    /// Fewest delays before the fit replaces the prior.
    pub min_samples: usize,
    /// Prior used until then (and when the window is degenerate).
    pub prior: GammaParams,
}

impl Default for WeightSettings {
    fn default() -> Self {
        Self { window: 50, min_samples: 10, prior: GammaParams { shape: 12.0, scale_s: 0.015 } }
    }
}

/// Scenario weights for the multi-stage controller, updated from observed delays.
#[derive(Debug, Clone)]
pub struct ScenarioWeights {
    settings: WeightSettings,
    window: DelayWindow,
    sampling_times_s: Vec<f64>,
    /// `Some` when the run has no delays: fixed weights.
    nominal: Option<Vec<f64>>,
    current: Vec<f64>,
    source: WeightSource,
}

impl ScenarioWeights {
    /// Weights over `sampling_times_s`; with `nominal` the weights are fixed (no delays).
    pub fn new(settings: WeightSettings, sampling_times_s: &[f64], nominal: Option<&[f64]>) -> Self {
        let mut s = Self {
            settings,
            window: DelayWindow::new(settings.window),
            sampling_times_s: sampling_times_s.to_vec(),
            nominal: nominal.map(|w| w.to_vec()),
            current: vec![0.0; sampling_times_s.len()],
            source: WeightSource::Prior(settings.prior),
        };
        s.refresh();
        s
    }

    /// Records an observed round-trip delay and recomputes the weights.
    pub fn observe(&mut self, delay_s: f64) {
        if self.window.push(delay_s) {
            self.refresh();
        }
    }

    fn refresh(&mut self) {
        if let Some(nominal) = &self.nominal {
            self.current.copy_from_slice(nominal);
            self.source = WeightSource::Nominal;
            return;
        }
        if let Some(fit) = self.window.fit(self.settings.min_samples)
            && weights_from_gamma(&fit, &self.sampling_times_s, &mut self.current)
        {
            self.source = WeightSource::Fitted(fit);
            return;
        }
        let prior = self.settings.prior;
        if weights_from_gamma(&prior, &self.sampling_times_s, &mut self.current) {
            self.source = WeightSource::Prior(prior);
        } else {
            // An invalid prior is refused by validation; keep uniform weights as a last resort.
            let m = self.current.len() as f64;
            self.current.iter_mut().for_each(|w| *w = 1.0 / m);
        }
    }

    pub fn weights(&self) -> &[f64] {
        &self.current
    }

    pub fn source(&self) -> WeightSource {
        self.source
    }

    pub fn window(&self) -> &DelayWindow {
        &self.window
    }
}

#[cfg(test)]
mod tests;
