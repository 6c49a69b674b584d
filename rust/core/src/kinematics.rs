//! How a CMM's carriages are stacked (docs/conventions.md, Machine
//! configurations): which carriage rides on which, and which of them carry
//! the probe and which the part. The order decides over which arms each
//! carriage's angular errors act.
//!
//! Every carriage sits on the base or on the one before it in its chain.
//! The probe chain runs from the base to the ram that carries the scanner;
//! the part chain (a moving table) from the base to the part. Map
//! components are what a laser interferometer measures: the motion of the
//! probe relative to the part, one axis moving, the others at zero. To
//! first order in the angles the position error is then
//!
//! ```text
//! e = sum_A d(A) + sum_A eps(A) x arm(A) + shear
//! ```
//!
//! where arm(A), for a carriage of the probe chain, is the displacement of
//! the carriages above it; for a carriage of the part chain, the
//! displacement of the whole probe chain and of the part chain's carriages
//! below it. (A carriage's own travel does not enter its arm: it is in its
//! measured straightness.) The probe's rotation relative to the part is the
//! sum of every carriage's angles whatever the stacking, so only the arms
//! differ between configurations. The thesis machine (X bridge on the
//! table, Y on the bridge, Z ram on Y) gives arm(X) = (0, E, F), arm(Y) =
//! (0, 0, F), arm(Z) = 0: eqs. 11-13.

use crate::error::{CoreError, Result};

/// What a carriage carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The scanner (through the carriages above it).
    Probe,
    /// The part (a moving table).
    Part,
}

impl Side {
    /// 'probe' or 'part', as machine files and map states name it.
    pub fn name(self) -> &'static str {
        match self {
            Side::Probe => "probe",
            Side::Part => "part",
        }
    }

    /// The side named `name` ('probe' or 'part').
    pub fn from_name(name: &str) -> Option<Side> {
        match name {
            "probe" => Some(Side::Probe),
            "part" => Some(Side::Part),
            _ => None,
        }
    }
}

/// The stacking of the three carriages, from the base up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kinematics {
    /// (carriage 0 = X, 1 = Y, 2 = Z; what it carries), from the base up:
    /// within each side, a carriage rides on the one before it.
    stack: Stack,
    /// The configuration's name, when it is a named one (a gantry and a
    /// moving bridge share a stacking but not a name).
    name: Option<&'static str>,
}

/// A stacking from the base up: (carriage, what it carries).
type Stack = [(usize, Side); 3];

/// The named configurations: (name, stacking, one line).
const NAMED: &[(&str, Stack, &str)] = &[
    (
        "thesis",
        [(0, Side::Probe), (1, Side::Probe), (2, Side::Probe)],
        "moving bridge with an X-Y-Z chain (the thesis's DEA Iota 1102): X bridge, Y carriage on it, Z ram",
    ),
    (
        "moving-bridge",
        [(1, Side::Probe), (0, Side::Probe), (2, Side::Probe)],
        "moving bridge with a Y-X-Z chain: the bridge travels along Y, the X carriage on it, the Z ram",
    ),
    (
        "gantry",
        [(1, Side::Probe), (0, Side::Probe), (2, Side::Probe)],
        "gantry: the beam travels along Y on raised rails, the X carriage on it, the Z ram",
    ),
    (
        "fixed-bridge",
        [(1, Side::Part), (0, Side::Probe), (2, Side::Probe)],
        "fixed bridge: the table carries the part along Y, the X carriage on the bridge, the Z ram",
    ),
    (
        "horizontal-arm",
        [(0, Side::Probe), (2, Side::Probe), (1, Side::Probe)],
        "horizontal arm: the column travels along X, the carriage along Z on it, the arm along Y",
    ),
];

impl Default for Kinematics {
    fn default() -> Self {
        Kinematics::thesis()
    }
}

impl Kinematics {
    /// The thesis machine: X, Y, Z all on the probe side, X at the base.
    pub fn thesis() -> Self {
        Kinematics {
            stack: NAMED[0].1,
            name: Some(NAMED[0].0),
        }
    }

    /// A stacking from the base up; each carriage exactly once.
    pub fn new(stack: [(usize, Side); 3]) -> Result<Self> {
        let mut seen = [false; 3];
        for (a, _) in stack {
            if a > 2 || seen[a] {
                return Err(CoreError::invalid_argument(
                    "kinematics",
                    format!("each of X, Y, Z must appear once in the stacking, got {stack:?}"),
                ));
            }
            seen[a] = true;
        }
        Ok(Kinematics { stack, name: None })
    }

    /// The named configuration `name` (see [`Kinematics::names`]).
    pub fn named(name: &str) -> Result<Self> {
        NAMED
            .iter()
            .find(|(n, _, _)| *n == name)
            .map(|(n, stack, _)| Kinematics {
                stack: *stack,
                name: Some(*n),
            })
            .ok_or_else(|| {
                CoreError::invalid_argument(
                    "kinematics",
                    format!(
                        "unknown configuration {name:?} (known: {})",
                        NAMED
                            .iter()
                            .map(|(n, _, _)| *n)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })
    }

    /// (name, one-line description) of every named configuration.
    pub fn names() -> Vec<(&'static str, &'static str)> {
        NAMED.iter().map(|(n, _, d)| (*n, *d)).collect()
    }

    /// The configuration's name, or `None` for a stacking built with
    /// [`Kinematics::new`].
    pub fn name(&self) -> Option<&'static str> {
        self.name
    }

    /// The stacking from the base up.
    pub fn stack(&self) -> [(usize, Side); 3] {
        self.stack
    }

    /// The carriages of one side, from the base up.
    pub fn chain(&self, side: Side) -> impl Iterator<Item = usize> + '_ {
        self.stack
            .iter()
            .filter(move |(_, s)| *s == side)
            .map(|(a, _)| *a)
    }

    /// arms[A][B] = 1 when carriage B's travel is in carriage A's arm, else
    /// 0 (see the module's documentation).
    pub fn arms(&self) -> [[f64; 3]; 3] {
        let mut arms = [[0.0; 3]; 3];
        let probe: Vec<usize> = self.chain(Side::Probe).collect();
        let part: Vec<usize> = self.chain(Side::Part).collect();
        for (k, &a) in probe.iter().enumerate() {
            for &b in &probe[k + 1..] {
                arms[a][b] = 1.0;
            }
        }
        for (k, &a) in part.iter().enumerate() {
            for &b in probe.iter().chain(&part[..k]) {
                arms[a][b] = 1.0;
            }
        }
        arms
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_thesis_arms_are_eqs_11_to_13() {
        assert_eq!(
            Kinematics::thesis().arms(),
            [[0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
        );
    }

    #[test]
    fn a_table_axis_sees_the_whole_probe_chain() {
        let k = Kinematics::named("fixed-bridge").unwrap();
        // Y (the table) under X and Z; X under Z; to first order the same as
        // a Y-X-Z moving bridge.
        assert_eq!(
            k.arms(),
            [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
        );
        assert_eq!(k.arms(), Kinematics::named("moving-bridge").unwrap().arms());
        let (gantry, bridge) = (
            Kinematics::named("gantry").unwrap(),
            Kinematics::named("moving-bridge").unwrap(),
        );
        assert_eq!(gantry.stack(), bridge.stack());
        assert_eq!(
            (gantry.name(), bridge.name()),
            (Some("gantry"), Some("moving-bridge"))
        );
        let arm = Kinematics::named("horizontal-arm").unwrap().arms();
        assert_eq!(arm, [[0.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    }

    #[test]
    fn names_and_bad_stackings() {
        for (n, _) in Kinematics::names() {
            let k = Kinematics::named(n).unwrap();
            assert_eq!(Kinematics::named(k.name().unwrap()).unwrap(), k);
        }
        let e = Kinematics::named("cantilever").unwrap_err().to_string();
        assert!(
            e.contains("cantilever") && e.contains("moving-bridge"),
            "{e}"
        );
        assert!(Kinematics::new([(0, Side::Probe), (0, Side::Probe), (2, Side::Part)]).is_err());
    }
}
