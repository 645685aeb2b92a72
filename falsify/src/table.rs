//! The `[falsify]` table of a scenario file: what `hilbench falsify` searches, for which
//! failure, with which method and budget.
//!
//! ```toml
//! [falsify]
//! budget = 300                # runs per search (--budget overrides; default 300)
//! seed = 1                    # seed of the search (--seed overrides; default scenario.seed)
//! method = "cmaes"            # or "random": the baseline, the same space and budget
//! property = "collision"      # or "collision_or_miss", or { clearance_below_m = 0.05 }
//! families = ["gamma"]        # [sweep] families to search, one search each (default: all)
//! max_delay_s = 0.33          # a family's delays clipped here (default: [sweep]'s)
//! population = 8              # CMA-ES's population (default 4 + 3 ln n)
//! sigma0 = 0.3                # CMA-ES's first step, a fraction of each range (default 0.3)
//! warmup = 16                 # CMA-ES first flies 16 random points, starts at the best (default 0)
//!
//! [falsify.signal]            # a segment-wise delay signal over the run's time
//! points = 3                  # control points (1 to 8)
//! interpolation = "constant"  # levels held between switch times, or "linear" between points
//! duration_s = 12.0           # where the points' times lie; the last level holds after it
//! min_delay_s = 0.0           # the levels' range, s
//! max_delay_s = 0.33
//! free_times = true           # the times are searched too (else evenly spaced)
//! ```
//!
//! The table's own checks are [`FalsifyTable::validate`]; whether `families` names families of
//! the file's `[sweep]` is the scenario file loader's (it sees both tables).

/// Runs per search when neither the file nor the command line says.
pub const DEFAULT_BUDGET: u64 = 300;
/// The most runs per search, in the file as on the command line (`--budget`): a million runs
/// of a second each is eleven days of one core.
pub const MAX_BUDGET: u64 = 1_000_000;
/// CMA-ES's first step in the unit cube when the file does not say.
pub const DEFAULT_SIGMA0: f64 = 0.3;
/// The most control points of a signal (published falsifiers use 2 to 4).
pub const MAX_POINTS: u32 = 8;

/// How a search picks the runs it flies.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// CMA-ES with restarts (IPOP: each restart doubles the population), in the unit cube of
    /// the space's ranges.
    #[default]
    Cmaes,
    /// Points drawn uniformly from the same space: a sweep restricted to the space, the
    /// baseline.
    Random,
}

impl Method {
    /// As written in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Cmaes => "cmaes",
            Method::Random => "random",
        }
    }
}

/// The failure searched for; a run fails when its score ([`crate::RunFacts`]) is negative.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Property {
    /// Any entry into a cylinder or the ground.
    #[default]
    Collision,
    /// A collision, or the goal not reached by the time limit.
    CollisionOrMiss,
    /// A clearance to some cylinder below this, m (a collision included).
    ClearanceBelowM(f64),
}

impl Property {
    /// As written in files (`clearance_below_m=X` for the last).
    pub fn name(self) -> String {
        match self {
            Property::Collision => "collision".into(),
            Property::CollisionOrMiss => "collision_or_miss".into(),
            Property::ClearanceBelowM(x) => format!("clearance_below_m={x}"),
        }
    }
}

/// How a signal's levels connect.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    /// Each level holds until the next switch time (`points` levels, `points - 1` switches).
    #[default]
    Constant,
    /// Straight lines between `points` (time, level) control points.
    Linear,
}

fn yes() -> bool {
    true
}

/// `[falsify.signal]`: a segment-wise delay signal, the round-trip delay as a function of the
/// time a command is sent.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignalTable {
    /// Control points, 1 to [`MAX_POINTS`].
    pub points: u32,
    #[serde(default)]
    pub interpolation: Interpolation,
    /// The control points' times lie in `[0, duration_s]`; the last level holds after, s.
    pub duration_s: f64,
    /// The smallest level, s.
    #[serde(default)]
    pub min_delay_s: f64,
    /// The largest level, s.
    pub max_delay_s: f64,
    /// Search the control points' times too (else evenly spaced over `duration_s`).
    #[serde(default = "yes")]
    pub free_times: bool,
}

/// The `[falsify]` table.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FalsifyTable {
    /// Runs per search (`--budget` overrides; default [`DEFAULT_BUDGET`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<u64>,
    /// Seed of the search (`--seed` overrides; default `scenario.seed`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    #[serde(default)]
    pub method: Method,
    #[serde(default)]
    pub property: Property,
    /// `[sweep]` families to search, one search each (absent: every family of `[sweep]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub families: Option<Vec<String>>,
    /// A family's delays are clipped here, s (default: `[sweep]`'s `max_delay_s`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_delay_s: Option<f64>,
    /// CMA-ES's population per generation (default `4 + floor(3 ln n)`), and random search's
    /// batch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub population: Option<u64>,
    /// CMA-ES's first step, as a fraction of each range (default [`DEFAULT_SIGMA0`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma0: Option<f64>,
    /// CMA-ES first flies this many random points (random search's first, for the same seed)
    /// and starts at the best of them (default 0: at a random point, unflown).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signal: Option<SignalTable>,
}

impl FalsifyTable {
    /// `(field path, reason)` of the first bad key, paths under `falsify`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let bad = |key: &str, reason: &str| Err((format!("falsify.{key}"), reason.to_string()));
        if self.budget.is_some_and(|b| !(1..=MAX_BUDGET).contains(&b)) {
            return bad("budget", &format!("must be 1 to {MAX_BUDGET} runs"));
        }
        if let Property::ClearanceBelowM(x) = self.property
            && !(x.is_finite() && (0.0..=100.0).contains(&x))
        {
            return bad("property.clearance_below_m", "must be in [0, 100] m");
        }
        if let Some(m) = self.max_delay_s
            && !(m.is_finite() && m > 0.0 && m <= delay::MAX_DELAY_S)
        {
            return bad("max_delay_s", &format!("must be in (0, {}] s", delay::MAX_DELAY_S));
        }
        if let Some(p) = self.population
            && !(2..=10_000).contains(&p)
        {
            return bad("population", "must be in [2, 10000]");
        }
        if let Some(s) = self.sigma0
            && !(s.is_finite() && s > 0.0 && s <= 1.0)
        {
            return bad("sigma0", "must be in (0, 1] (a fraction of each range)");
        }
        if self.warmup.is_some_and(|w| w > 1_000_000) {
            return bad("warmup", "must be at most 1000000 runs");
        }
        if let Some(families) = &self.families {
            for (i, name) in families.iter().enumerate() {
                if families[..i].contains(name) {
                    return bad(&format!("families[{i}]"), &format!("{name:?} is listed twice"));
                }
            }
        }
        if let Some(s) = &self.signal {
            if !(1..=MAX_POINTS).contains(&s.points) {
                return bad("signal.points", &format!("must be in [1, {MAX_POINTS}]"));
            }
            if !(s.duration_s.is_finite() && s.duration_s > 0.0 && s.duration_s <= 86_400.0) {
                return bad("signal.duration_s", "must be in (0, 86400] s");
            }
            if !(s.min_delay_s.is_finite() && s.min_delay_s >= 0.0) {
                return bad("signal.min_delay_s", "must be a finite number >= 0 s");
            }
            if !(s.max_delay_s.is_finite() && s.max_delay_s <= delay::MAX_DELAY_S) {
                return bad("signal.max_delay_s", &format!("must be at most {} s", delay::MAX_DELAY_S));
            }
            if s.max_delay_s <= s.min_delay_s {
                return bad("signal.max_delay_s", "must be above min_delay_s");
            }
        }
        if self.families.as_ref().is_some_and(Vec::is_empty) && self.signal.is_none() {
            return bad("families", "is empty and there is no [falsify.signal]: nothing to search");
        }
        Ok(())
    }

    /// The budget: the command line's, else the file's, else [`DEFAULT_BUDGET`].
    pub fn budget_or_default(&self) -> u64 {
        self.budget.unwrap_or(DEFAULT_BUDGET)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> FalsifyTable {
        toml::from_str(text).unwrap_or_else(|e| panic!("{e}"))
    }

    fn field_of(text: &str) -> String {
        match table(text).validate() {
            Ok(()) => panic!("accepted: {text}"),
            Err((field, _)) => field,
        }
    }

    const SIGNAL: &str = "[signal]\npoints = 3\nduration_s = 12.0\nmax_delay_s = 0.33\n";

    #[test]
    fn a_table_reads_with_its_defaults_and_every_property_form() {
        let t = table(SIGNAL);
        assert_eq!(t.validate(), Ok(()));
        assert_eq!((t.method, t.property, t.budget_or_default()), (Method::Cmaes, Property::Collision, 300));
        let s = t.signal.expect("a signal");
        assert_eq!((s.interpolation, s.min_delay_s, s.free_times), (Interpolation::Constant, 0.0, true));
        let t =
            table("method = \"random\"\nproperty = \"collision_or_miss\"\nbudget = 50\nfamilies = [\"a\"]");
        assert_eq!((t.method, t.property, t.budget), (Method::Random, Property::CollisionOrMiss, Some(50)));
        let t = table("property = { clearance_below_m = 0.05 }\nfamilies = [\"a\"]");
        assert_eq!(t.property, Property::ClearanceBelowM(0.05));
        assert_eq!(t.property.name(), "clearance_below_m=0.05");
    }

    #[test]
    fn bad_values_are_refused_naming_the_field() {
        assert_eq!(field_of(&format!("budget = 0\n{SIGNAL}")), "falsify.budget");
        assert_eq!(
            field_of(&format!("budget = 10000000000\n{SIGNAL}")),
            "falsify.budget",
            "over --budget's cap"
        );
        assert_eq!(table(&format!("budget = {MAX_BUDGET}\n{SIGNAL}")).validate(), Ok(()), "at the cap");
        assert_eq!(
            field_of(&format!("property = {{ clearance_below_m = -1.0 }}\n{SIGNAL}")),
            "falsify.property.clearance_below_m"
        );
        assert_eq!(field_of(&format!("max_delay_s = 0.0\n{SIGNAL}")), "falsify.max_delay_s");
        assert_eq!(field_of(&format!("population = 1\n{SIGNAL}")), "falsify.population");
        assert_eq!(field_of(&format!("sigma0 = 1.5\n{SIGNAL}")), "falsify.sigma0");
        assert_eq!(field_of(&format!("sigma0 = nan\n{SIGNAL}")), "falsify.sigma0");
        assert_eq!(field_of(&format!("warmup = 2000000\n{SIGNAL}")), "falsify.warmup");
        assert_eq!(field_of("families = [\"a\", \"a\"]"), "falsify.families[1]");
        assert_eq!(field_of("families = []"), "falsify.families");
        let signal = |body: &str| format!("[signal]\n{body}");
        assert_eq!(
            field_of(&signal("points = 0\nduration_s = 1.0\nmax_delay_s = 0.3")),
            "falsify.signal.points"
        );
        assert_eq!(
            field_of(&signal("points = 9\nduration_s = 1.0\nmax_delay_s = 0.3")),
            "falsify.signal.points"
        );
        assert_eq!(
            field_of(&signal("points = 2\nduration_s = 0.0\nmax_delay_s = 0.3")),
            "falsify.signal.duration_s"
        );
        assert_eq!(
            field_of(&signal("points = 2\nduration_s = 5.0\nmin_delay_s = -0.1\nmax_delay_s = 0.3")),
            "falsify.signal.min_delay_s"
        );
        assert_eq!(
            field_of(&signal("points = 2\nduration_s = 5.0\nmin_delay_s = 0.3\nmax_delay_s = 0.3")),
            "falsify.signal.max_delay_s"
        );
        assert_eq!(
            field_of(&signal("points = 2\nduration_s = 5.0\nmax_delay_s = 1e9")),
            "falsify.signal.max_delay_s"
        );
        // Unknown keys and unknown names are serde's, with the key or the value named.
        for (text, says) in [
            ("budgett = 3", "unknown field `budgett`"),
            ("method = \"cma\"", "unknown variant `cma`"),
            ("property = \"collisions\"", "unknown variant `collisions`"),
            ("[signal]\npoints = 2\nduration_s = 5.0\nmax_delay_s = 0.3\nloss = 0.1", "unknown field `loss`"),
            ("[signal]\npoints = 2\nduration_s = 5.0\nmax_delay_s = 0.3\ninterpolation = \"cubic\"", "cubic"),
        ] {
            let e = toml::from_str::<FalsifyTable>(text).map_err(|e| e.to_string());
            assert!(e.as_ref().is_err_and(|m| m.contains(says)), "{text}: {e:?}");
        }
    }
}
