//! The `[falsify]` table in a scenario file (its type and its own checks are
//! `falsify::table`'s): the checks that need the file's `[sweep]`, and the search spaces the two
//! tables describe.
//!
//! `families` names `[sweep]` families (absent: all of them that have a range); each becomes a space of its ranged
//! parameters ([`falsify::Space::family`]: the dims in the order `Family::table` draws them, a
//! point's table drawn with the search's process seed and clipped at `max_delay_s`), and
//! `[falsify.signal]` one more ([`falsify::Space::signal`]).

use std::sync::Arc;

use falsify::{Dim, FalsifyTable, Space};

use crate::sweep_table::{Family, SweepSection};

/// `(field path, reason)` of the first bad key of `table` in a file whose `[sweep]` is `sweep`.
pub fn validate(table: &FalsifyTable, sweep: Option<&SweepSection>) -> Result<(), (String, String)> {
    table.validate()?;
    let families = sweep.map_or(&[][..], |s| &s.families[..]);
    if let Some(names) = &table.families {
        for (i, name) in names.iter().enumerate() {
            let field = format!("falsify.families[{i}]");
            let Some(f) = families.iter().find(|f| f.name() == name) else {
                let known: Vec<&str> = families.iter().map(Family::name).collect();
                return Err((
                    field,
                    format!("{name:?} is no family of [sweep] (it has: {})", known.join(", ")),
                ));
            };
            if f.kind == "traces" {
                return Err((
                    field,
                    format!("{name:?} is a folder of traces: it has no parameters to search"),
                ));
            }
            if !has_ranges(f) {
                return Err((
                    field,
                    format!("{name:?} has no range [min, max]: it is one process, nothing to search"),
                ));
            }
        }
    } else if table.signal.is_none() && !families.iter().any(has_ranges) {
        return Err((
            "falsify".into(),
            "nothing to search: no [sweep] family with parameters and no [falsify.signal]".into(),
        ));
    }
    Ok(())
}

/// The spaces of a validated `table`: the families' (in the table's order, else `[sweep]`'s,
/// those without a range left out: a fixed process or a folder of traces), then the signal's. `process_seed` seeds every family's process.
pub fn spaces(table: &FalsifyTable, sweep: Option<&SweepSection>, process_seed: u64) -> Vec<Space> {
    let families = sweep.map_or(&[][..], |s| &s.families[..]);
    let clip = table.max_delay_s.or(sweep.and_then(|s| s.max_delay_s)).unwrap_or(delay::MAX_DELAY_S);
    let chosen: Vec<&Family> = match &table.families {
        Some(names) => names.iter().filter_map(|n| families.iter().find(|f| f.name() == n)).collect(),
        None => families.iter().filter(|f| has_ranges(f)).collect(),
    };
    let mut spaces: Vec<Space> = chosen.into_iter().map(|f| family_space(f, process_seed, clip)).collect();
    if let Some(signal) = &table.signal {
        spaces.push(Space::signal(signal));
    }
    spaces
}

/// Whether `family` has a parameter to search (a range; not a folder of traces).
fn has_ranges(family: &Family) -> bool {
    family.kind != "traces" && family_space(family, 0, 1.0).dims.iter().any(|d| d.hi > d.lo)
}

/// The space of `family`'s ranged parameters.
pub fn family_space(family: &Family, process_seed: u64, max_delay_s: f64) -> Space {
    let mut dims = Vec::new();
    family.table(
        &mut |key, lo, hi| {
            dims.push(Dim::new(key, lo, hi));
            lo
        },
        &mut |_| 0,
    );
    let own = family.clone();
    let table = Arc::new(move |point: &[f64]| {
        let mut i = 0;
        own.table(
            &mut |_, lo, hi| {
                let v = point.get(i).copied().unwrap_or(lo).clamp(lo, hi);
                i += 1;
                v
            },
            &mut |_| 0,
        )
        .0
    });
    Space::family(family.name(), dims, table, process_seed, max_delay_s)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SWEEP: &str = "max_delay_s = 0.33\n[[families]]\nkind = \"gamma\"\nshape = [1.0, 30.0]\nscale_s = [0.002, 0.04]\n\
        [[families]]\nname = \"bursts\"\nkind = \"regime\"\n\
        [[families.states]]\nkind = \"constant\"\ndelay_s = [0.0, 0.06]\nmean_dwell_messages = 20\n\
        [[families.states]]\nkind = \"constant\"\ndelay_s = [0.15, 0.33]\nmean_dwell_messages = [1.0, 14.0]\n";

    fn parse<T: serde::de::DeserializeOwned>(text: &str) -> T {
        toml::from_str(text).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn every_family_and_the_signal_become_spaces_with_their_ranges() {
        let sweep: SweepSection = parse(SWEEP);
        let table: FalsifyTable = parse("[signal]\npoints = 2\nduration_s = 10.0\nmax_delay_s = 0.5\n");
        assert_eq!(validate(&table, Some(&sweep)), Ok(()));
        let spaces = spaces(&table, Some(&sweep), 3);
        let names: Vec<&str> = spaces.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["gamma", "bursts", "signal"]);
        assert_eq!(spaces[0].dims, [Dim::new("shape", 1.0, 30.0), Dim::new("scale_s", 0.002, 0.04)]);
        let dims: Vec<&str> = spaces[1].dims.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(dims, ["states[0].delay_s", "states[1].delay_s", "states[1].mean_dwell_messages"]);
        // A point's delays: the family's process at the point, clipped at [sweep]'s 0.33 s.
        let scenario = mav::Scenario::paper_2();
        let d = spaces[0].delays(&[30.0, 0.04], &scenario).expect("delays");
        assert!(d.iter().all(|d| *d <= 0.33) && d.contains(&0.33));
        let d = spaces[1].delays(&[0.0, 0.2, 1.0], &scenario).expect("delays");
        assert!(d.iter().all(|d| *d == 0.0 || *d == 0.2), "two levels only");
    }

    #[test]
    fn families_must_be_the_sweeps_and_have_parameters() {
        let sweep: SweepSection = parse(SWEEP);
        let bad = |text: &str, sweep: Option<&SweepSection>| {
            validate(&parse(text), sweep)
                .err()
                .map(|(field, _)| field)
                .unwrap_or_else(|| panic!("accepted: {text}"))
        };
        assert_eq!(bad("families = [\"gamma\", \"uniform\"]", Some(&sweep)), "falsify.families[1]");
        assert_eq!(bad("families = [\"gamma\"]", None), "falsify.families[0]");
        assert_eq!(bad("budget = 5", None), "falsify");
        let traces: SweepSection = parse("[[families]]\nkind = \"traces\"\ndir = \"t\"\n");
        assert_eq!(bad("families = [\"traces\"]", Some(&traces)), "falsify.families[0]");
        assert_eq!(bad("budget = 5", Some(&traces)), "falsify");
        let fixed: SweepSection = parse("[[families]]\nkind = \"uniform\"\nmin_s = 0.0\nmax_s = 0.33\n");
        assert_eq!(bad("families = [\"uniform\"]", Some(&fixed)), "falsify.families[0]");
        assert_eq!(bad("budget = 5", Some(&fixed)), "falsify");
        let table: FalsifyTable = parse("families = [\"bursts\"]\nmax_delay_s = 0.2");
        assert_eq!(validate(&table, Some(&sweep)), Ok(()));
        let spaces = spaces(&table, Some(&sweep), 3);
        assert_eq!(spaces.len(), 1);
        let d = spaces[0].delays(&[0.0, 0.33, 14.0], &mav::Scenario::paper_2()).expect("delays");
        assert!(d.contains(&0.2) && d.iter().all(|d| *d <= 0.2), "the table's max_delay_s");
    }
}
