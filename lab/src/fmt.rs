//! Fixed-width printing of the records' vectors (`cycles`, `delay-probe`).

/// `v`'s values with two decimals, each `width` wide, joined by `sep`.
pub fn fixed(v: &[f64], width: usize, sep: &str) -> String {
    v.iter().map(|x| format!("{x:width$.2}")).collect::<Vec<_>>().join(sep)
}
