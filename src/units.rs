//! Length units. glTF is in metres, so a cloud in millimetres written as-is becomes a mesh a
//! thousand times too large in every viewer; `--units` (and the page's setting) scales the
//! output to metres. When the units are not given, [`guess`] says what the extent suggests.

use std::fmt;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Units {
    Millimetres,
    Centimetres,
    Metres,
    Inches,
    Feet,
}

impl Units {
    pub const ALL: [Units; 5] = [Units::Millimetres, Units::Centimetres, Units::Metres, Units::Inches, Units::Feet];

    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Units::Millimetres => 1e-3,
            Units::Centimetres => 1e-2,
            Units::Metres => 1.0,
            Units::Inches => 0.0254,
            Units::Feet => 0.3048,
        }
    }

    /// The short name used on the command line and in share links.
    pub fn code(self) -> &'static str {
        match self {
            Units::Millimetres => "mm",
            Units::Centimetres => "cm",
            Units::Metres => "m",
            Units::Inches => "in",
            Units::Feet => "ft",
        }
    }
}

impl fmt::Display for Units {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.code())
    }
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Units::ALL
            .into_iter()
            .find(|u| u.code() == s)
            .ok_or_else(|| format!("unknown units '{s}' (expected mm, cm, m, in or ft)"))
    }
}

/// What a cloud's size suggests about its units.
#[derive(Clone, Debug, PartialEq)]
pub struct UnitsGuess {
    /// The likeliest units, when the size points somewhere.
    pub units: Option<Units>,
    /// One sentence: the size, and what it would mean.
    pub reason: String,
    /// Whether the user should be warned when they give no units: the extent suggests
    /// millimetres, and glTF's metres would make the mesh 1000 times too large.
    pub warn: bool,
    /// The file states its units (or its format fixes them, as LAS's metres): the units are a
    /// fact, not a guess from the size.
    pub stated: bool,
}

/// The units a cloud's longest side `longest` (in file units) suggests. `stated` are units the
/// file itself states (E57 is in metres), which win.
///
/// Scans of objects are 2 cm to 5 m across; in millimetres they span 20 to 5000 units, which in
/// metres would be a building or a street. Below 20 units, metres (or another unit the user
/// must give) is the likelier reading; beyond 5000, a site or terrain in metres or feet.
pub fn guess(longest: f64, stated: Option<Units>) -> UnitsGuess {
    if let Some(u) = stated {
        return UnitsGuess { units: Some(u), reason: format!("the file states {u}"), warn: false, stated: true };
    }
    let l = format!("{longest:.4}");
    let l = l.trim_end_matches('0').trim_end_matches('.');
    if longest > 20.0 && longest <= 5000.0 {
        UnitsGuess {
            units: Some(Units::Millimetres),
            reason: format!(
                "the longest side is {l} units: millimetres if this is an object ({:.3} m), metres only if it is a building or a site",
                longest * 1e-3
            ),
            warn: true,
            stated: false,
        }
    } else if longest <= 20.0 {
        UnitsGuess {
            units: Some(Units::Metres),
            reason: format!("the longest side is {l} units: plausible in metres"),
            warn: false,
            stated: false,
        }
    } else {
        UnitsGuess {
            units: None,
            reason: format!("the longest side is {l} units: a site or terrain, in metres or feet"),
            warn: false,
            stated: false,
        }
    }
}

/// `positions` (relative to `origin`) in metres when `units` are given: a similarity, so
/// normals keep; returns the origin in metres too.
pub fn to_metres(units: Option<Units>, positions: &mut [[f32; 3]], origin: [f64; 3]) -> [f64; 3] {
    let Some(s) = units.map(Units::metres).filter(|&s| s != 1.0) else { return origin };
    for p in positions {
        *p = p.map(|c| (c as f64 * s) as f32);
    }
    origin.map(|c| c * s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip() {
        for u in Units::ALL {
            assert_eq!(u.code().parse::<Units>(), Ok(u));
        }
        assert!("metres".parse::<Units>().is_err());
    }

    #[test]
    fn guesses() {
        assert_eq!(guess(0.3, None).units, Some(Units::Metres));
        let mm = guess(243.0, None);
        assert_eq!(mm.units, Some(Units::Millimetres));
        assert!(mm.warn && mm.reason.contains("243 units"), "{}", mm.reason);
        assert!(!guess(243.0, Some(Units::Metres)).warn);
        assert_eq!(guess(1e5, None).units, None);
    }
}
