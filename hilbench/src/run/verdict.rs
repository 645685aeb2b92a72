//! What a run amounts to once counted: the [`Verdict`] of `runs.csv`'s `outcome`, a
//! falsification's evaluations, a shrunk failure and the counts of `sweep.json`. Its names are
//! stable file contents: they are written and read here only ([`Verdict::name`], `FromStr`).

use super::RunErrorKind;

/// The verdict on one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// It reached its goal without a collision (`reached`).
    Reached,
    /// It entered a cylinder or the ground, whatever ended it (`collided`).
    Collided,
    /// It ended without reaching its goal and without a collision: the time limit, or a stop
    /// the scenario asks for (`missed`).
    Missed,
    /// It stopped before its end: by the controller's doing (`aborted`: its own error, a
    /// freeze, an early exit), or the bench's (`error`: a trace that ran out, a service that
    /// died, a run that could not start).
    Failed(RunErrorKind),
    /// It outlived the per-run time limit (`timeout`).
    TimedOut,
}

impl Verdict {
    /// Every verdict, in the order `runs.csv`'s documentation lists them.
    pub const ALL: [Verdict; 6] = [
        Verdict::Reached,
        Verdict::Collided,
        Verdict::Missed,
        Verdict::Failed(RunErrorKind::Controller),
        Verdict::Failed(RunErrorKind::Bench),
        Verdict::TimedOut,
    ];

    /// The stable name (`runs.csv`, `sweep.json`, `falsify.json`).
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Reached => "reached",
            Verdict::Collided => "collided",
            Verdict::Missed => "missed",
            Verdict::Failed(RunErrorKind::Controller) => "aborted",
            Verdict::Failed(RunErrorKind::Bench) => "error",
            Verdict::TimedOut => "timeout",
        }
    }

    pub fn is_reached(self) -> bool {
        self == Verdict::Reached
    }

    /// A failure of the controller, and so of any property asked of it: a collision, a missed
    /// goal, or the controller stopping the run.
    pub fn fails_the_controller(self) -> bool {
        matches!(self, Verdict::Collided | Verdict::Missed | Verdict::Failed(RunErrorKind::Controller))
    }

    /// The run judged the controller: it flew to an end, or the controller stopped it. The
    /// bench's errors and time-outs say nothing of the controller and are not counted as runs
    /// of it (`sweep.json`'s failure probabilities).
    pub fn judges_the_controller(self) -> bool {
        !matches!(self, Verdict::Failed(RunErrorKind::Bench) | Verdict::TimedOut)
    }

    /// The bench's own error or a time-out (`sweep.json`'s `errors`).
    pub fn is_the_benchs(self) -> bool {
        !self.judges_the_controller()
    }
}

impl From<mpc::RunOutcome> for Verdict {
    fn from(outcome: mpc::RunOutcome) -> Self {
        match outcome {
            mpc::RunOutcome::Collided => Verdict::Collided,
            mpc::RunOutcome::Reached => Verdict::Reached,
            mpc::RunOutcome::Missed => Verdict::Missed,
        }
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Verdict {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Verdict::ALL.into_iter().find(|v| v.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Verdict::ALL.iter().map(|v| v.name()).collect();
            format!("{s:?} is not an outcome (one of {})", names.join(", "))
        })
    }
}

/// In the JSON files a verdict is its name.
impl serde::Serialize for Verdict {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Verdict {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_verdict_reads_back_from_its_name_and_the_names_are_runs_csvs() {
        let names: Vec<&str> = Verdict::ALL.iter().map(|v| v.name()).collect();
        assert_eq!(names, ["reached", "collided", "missed", "aborted", "error", "timeout"]);
        for v in Verdict::ALL {
            assert_eq!(v.to_string().parse::<Verdict>(), Ok(v));
            assert_eq!(serde_json::json!(v), serde_json::json!(v.name()));
            assert_eq!(serde_json::from_value::<Verdict>(serde_json::json!(v.name())).ok(), Some(v));
        }
        let refused = "crashed".parse::<Verdict>().expect_err("not a verdict");
        assert!(refused.contains("\"crashed\"") && refused.contains("timeout"), "{refused}");
    }

    #[test]
    fn the_controller_is_judged_by_every_verdict_but_the_benchs_errors_and_fails_by_three() {
        let judged: Vec<Verdict> = Verdict::ALL.into_iter().filter(|v| v.judges_the_controller()).collect();
        assert_eq!(judged, Verdict::ALL[..4]);
        let failed: Vec<Verdict> = Verdict::ALL.into_iter().filter(|v| v.fails_the_controller()).collect();
        assert_eq!(failed, Verdict::ALL[1..4]);
        assert!(Verdict::ALL.iter().all(|v| v.is_the_benchs() != v.judges_the_controller()));
    }
}
