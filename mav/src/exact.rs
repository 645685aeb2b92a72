//! Fixed-length arrays from serde that refuse a wrong length. serde's own `[T; N]` and tuple
//! impls stop reading after `N` elements and leave the rest to the format, and `toml` does not
//! look: `start` with 9 values was cut to 8 without a word. These read the whole sequence and
//! refuse any other length, naming the length found (the format names the field and line).

use serde::de::{Deserialize, Deserializer, Error};

/// `#[serde(deserialize_with = "crate::exact::array")]`: exactly `N` numbers.
pub fn array<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    let len = v.len();
    v.try_into().map_err(|_| D::Error::invalid_length(len, &format!("exactly {N} numbers").as_str()))
}

/// `#[serde(deserialize_with = "crate::exact::pair")]`: exactly two numbers.
pub fn pair<'de, D: Deserializer<'de>>(d: D) -> Result<(f64, f64), D::Error> {
    let [a, b] = array::<D, 2>(d)?;
    Ok((a, b))
}

#[cfg(test)]
mod tests {
    #[derive(Debug, serde::Deserialize)]
    struct Holder {
        #[serde(deserialize_with = "super::array")]
        v: [f64; 3],
        #[serde(deserialize_with = "super::pair")]
        p: (f64, f64),
    }

    #[test]
    fn too_long_and_too_short_arrays_are_refused_with_their_length() {
        let ok: Holder = toml::from_str("v = [1, 2.5, 3]\np = [4, 5]").expect("exact");
        assert_eq!((ok.v, ok.p), ([1.0, 2.5, 3.0], (4.0, 5.0)));
        for (text, len) in [
            ("v = [1, 2, 3, 4]\np = [4, 5]", 4),
            ("v = [1, 2]\np = [4, 5]", 2),
            ("v = [1, 2, 3]\np = [4, 5, 6]", 3),
        ] {
            let e = toml::from_str::<Holder>(text).expect_err(text).to_string();
            assert!(e.contains(&format!("invalid length {len}")) && e.contains("exactly"), "{e}");
        }
    }
}
