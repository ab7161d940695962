//! Naming a method and its knobs: `occlusion_tree:k=32:variant=fme` on the
//! command line, `{"method": "occlusion_tree", "options": {"k": 32}}` in JSON.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// Every method name of DESIGN's contract, whether or not a scene supports
/// it; the standard registry has an entry for each but `auto`.
pub const METHOD_NAMES: [&str; 8] = [
    "frustum",
    "occlusion_tree",
    "supporting_planes",
    "horizon",
    "ddo",
    "gpu",
    "raster",
    "auto",
];

/// A method's knobs as text (`k` → `"32"`); each method parses its own.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MethodOptions(BTreeMap<String, String>);

/// A method name with its options.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MethodSpec {
    /// One of [`METHOD_NAMES`].
    pub name: String,
    /// Its knobs.
    pub options: MethodOptions,
}

/// Why a method or its options were refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MethodError {
    /// The name is none of DESIGN's methods.
    #[error("unknown method '{name}'; known methods: {}", METHOD_NAMES.join(", "))]
    Unknown {
        /// What the client asked for.
        name: String,
    },
    /// The method exists but this scene does not support it.
    #[error("method '{name}' is not supported by scene '{scene}'; it supports: {}", supported.join(", "))]
    Unsupported {
        /// What the client asked for.
        name: String,
        /// The scene asked.
        scene: String,
        /// What it does support.
        supported: Vec<String>,
    },
    /// An option the method does not have.
    #[error("unknown option '{option}' for method '{method}'{}", known_list(known))]
    UnknownOption {
        /// The method.
        method: String,
        /// The option named.
        option: String,
        /// The options it has.
        known: Vec<&'static str>,
    },
    /// An option with a value the method cannot use.
    #[error("option '{option}' of method '{method}' must be {expected}, got '{value}'")]
    InvalidOption {
        /// The method.
        method: String,
        /// The option named.
        option: String,
        /// Its value as given.
        value: String,
        /// What it must be.
        expected: String,
    },
    /// A `name:key=value` spec that does not parse.
    #[error("malformed method spec '{spec}': {problem}")]
    Malformed {
        /// The spec as given.
        spec: String,
        /// What is wrong.
        problem: String,
    },
    /// A request asks for a region of views (`radius`, `angle`) from a
    /// method that cannot answer for one.
    #[error("method '{name}' cannot answer for a region of views (radius or angle above 0): {reason}; use one of: {}", answering.join(", "))]
    NoRegions {
        /// The method.
        name: String,
        /// Why not.
        reason: String,
        /// The scene's methods that can.
        answering: Vec<String>,
    },
    /// A method the scene supports, released while unused, could not be
    /// built again ([`super::SceneMethods::release_unasked`]).
    #[error("method '{name}' of scene '{scene}' could not be prepared again: {reason}")]
    NotRebuilt {
        /// The method.
        name: String,
        /// The scene.
        scene: String,
        /// Why its build failed.
        reason: String,
    },
}

fn known_list(known: &[&str]) -> String {
    if known.is_empty() {
        "; it takes no options".into()
    } else {
        format!("; known: {}", known.join(", "))
    }
}

impl MethodOptions {
    /// No options.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets `key` to `value`.
    pub fn insert(&mut self, key: impl Into<String>, value: impl Into<String>) {
        self.0.insert(key.into(), value.into());
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The options in key order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &str)> {
        self.0.iter().map(|(k, v)| (k.as_str(), v.as_str()))
    }

    /// A reader for `method` that remembers which keys were taken, so
    /// [`OptionReader::finish`] can refuse the rest by name.
    pub fn reader<'a>(
        &'a self,
        method: &'static str,
        known: &'static [&'static str],
    ) -> OptionReader<'a> {
        OptionReader {
            options: self,
            method,
            known,
        }
    }
}

/// Reads a method's options and refuses those it does not know.
#[derive(Debug)]
pub struct OptionReader<'a> {
    options: &'a MethodOptions,
    method: &'static str,
    known: &'static [&'static str],
}

impl OptionReader<'_> {
    /// The value of a numeric option, or its default when absent; a value
    /// that does not parse or lies outside the range is refused, naming
    /// the range.
    pub fn ranged<T>(&self, option: &Ranged<T>) -> Result<T, MethodError>
    where
        T: FromStr + PartialOrd + fmt::Display + Copy,
    {
        debug_assert!(
            self.known.contains(&option.key),
            "{} is not declared",
            option.key
        );
        match self.options.0.get(option.key) {
            None => Ok(option.default),
            Some(text) => text
                .parse::<T>()
                .ok()
                .filter(|v| option.min <= *v && *v <= option.max)
                .ok_or_else(|| self.invalid(option.key, text, option.expected())),
        }
    }

    /// The value of a `true`/`false` option, or `default` when absent.
    pub fn flag(&self, key: &'static str, default: bool) -> Result<bool, MethodError> {
        debug_assert!(self.known.contains(&key), "{key} is not declared");
        match self.options.0.get(key) {
            None => Ok(default),
            Some(text) => text
                .parse()
                .map_err(|_| self.invalid(key, text, "true or false".into())),
        }
    }

    /// The value of an option that takes one of `choices`; absent, the first.
    pub fn choice(
        &self,
        key: &'static str,
        choices: &[&'static str],
    ) -> Result<&'static str, MethodError> {
        debug_assert!(self.known.contains(&key), "{key} is not declared");
        match self.options.0.get(key) {
            None => Ok(choices[0]),
            Some(text) => choices
                .iter()
                .find(|c| **c == text)
                .copied()
                .ok_or_else(|| self.invalid(key, text, or_list(choices))),
        }
    }

    fn invalid(&self, key: &str, value: &str, expected: String) -> MethodError {
        MethodError::InvalidOption {
            method: self.method.into(),
            option: key.into(),
            value: value.into(),
            expected,
        }
    }

    /// The method whose options these are.
    pub fn method(&self) -> &'static str {
        self.method
    }

    /// Refuses any option that is not among the known ones.
    pub fn finish(self) -> Result<(), MethodError> {
        match self
            .options
            .0
            .keys()
            .find(|k| !self.known.contains(&k.as_str()))
        {
            None => Ok(()),
            Some(k) => Err(MethodError::UnknownOption {
                method: self.method.into(),
                option: k.clone(),
                known: self.known.to_vec(),
            }),
        }
    }
}

/// A numeric option: its key, default and closed range, defined once for
/// validation, defaults and error messages alike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ranged<T> {
    /// Its key (`k`).
    pub key: &'static str,
    /// What kind of number, for messages (`a whole number`).
    pub noun: &'static str,
    /// Its value when absent.
    pub default: T,
    /// Smallest value accepted.
    pub min: T,
    /// Largest value accepted.
    pub max: T,
}

impl<T: fmt::Display> Ranged<T> {
    /// What a value must be: `a whole number from 1 to 1024`.
    pub fn expected(&self) -> String {
        format!("{} from {} to {}", self.noun, self.min, self.max)
    }
}

/// `a, b or c`.
fn or_list(choices: &[&str]) -> String {
    match choices {
        [] => String::new(),
        [one] => one.to_string(),
        [rest @ .., last] => format!("{} or {last}", rest.join(", ")),
    }
}

impl MethodSpec {
    /// A spec with no options. Whether a scene has the method is for
    /// [`super::SceneMethods::get`] to say; here the name must only look
    /// like one (lower-case letters, digits, `_`).
    pub fn named(name: &str) -> Result<Self, MethodError> {
        let looks_like_a_name = !name.is_empty()
            && name.len() <= 64
            && name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
        if !looks_like_a_name {
            return Err(MethodError::Unknown { name: name.into() });
        }
        Ok(MethodSpec {
            name: name.into(),
            options: MethodOptions::new(),
        })
    }
}

impl FromStr for MethodSpec {
    type Err = MethodError;

    /// Parses `name` or `name:key=value:key=value`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut parts = s.split(':');
        let mut spec = MethodSpec::named(parts.next().unwrap_or_default())?;
        for part in parts {
            let (k, v) = part.split_once('=').ok_or_else(|| MethodError::Malformed {
                spec: s.into(),
                problem: format!("'{part}' is not key=value"),
            })?;
            if k.is_empty() {
                return Err(MethodError::Malformed {
                    spec: s.into(),
                    problem: "an option has no name".into(),
                });
            }
            spec.options.insert(k, v);
        }
        Ok(spec)
    }
}

impl fmt::Display for MethodSpec {
    /// The command-line form, which [`MethodSpec::from_str`] reads back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name)?;
        for (k, v) in self.options.iter() {
            write!(f, ":{k}={v}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_round_trip() {
        let s: MethodSpec = "occlusion_tree:k=32:variant=fme".parse().unwrap();
        assert_eq!(s.name, "occlusion_tree");
        assert_eq!(
            s.options.iter().collect::<Vec<_>>(),
            vec![("k", "32"), ("variant", "fme")]
        );
        assert_eq!(s.to_string(), "occlusion_tree:k=32:variant=fme");
    }

    #[test]
    fn refusals_name_the_problem() {
        let e = "Octree!".parse::<MethodSpec>().unwrap_err();
        assert!(e.to_string().starts_with("unknown method 'Octree!'"), "{e}");
        let e = "frustum:k".parse::<MethodSpec>().unwrap_err();
        assert!(e.to_string().contains("'k' is not key=value"), "{e}");
        let s: MethodSpec = "frustum:k=3".parse().unwrap();
        let e = s.options.reader("frustum", &[]).finish().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown option 'k' for method 'frustum'; it takes no options"
        );
    }

    const K: Ranged<u32> = Ranged {
        key: "k",
        noun: "a whole number",
        default: 8,
        min: 1,
        max: 64,
    };

    #[test]
    fn reader_parses_values_within_their_range() {
        let read = |spec: &str| {
            let s: MethodSpec = spec.parse().unwrap();
            s.options.reader("occlusion_tree", &["k"]).ranged(&K)
        };
        assert_eq!(read("occlusion_tree"), Ok(8));
        assert_eq!(read("occlusion_tree:k=64"), Ok(64));
        for bad in ["abc", "0", "65", "-1"] {
            let e = read(&format!("occlusion_tree:k={bad}")).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!(
                    "option 'k' of method 'occlusion_tree' must be a whole number from 1 to 64, got '{bad}'"
                )
            );
        }
    }

    #[test]
    fn floats_out_of_range_and_nan_are_refused() {
        const L: Ranged<f64> = Ranged {
            key: "lambda",
            noun: "a distance",
            default: 100.0,
            min: 0.001,
            max: 1e9,
        };
        for bad in ["NaN", "inf", "0", "2e9"] {
            let s: MethodSpec = format!("x:lambda={bad}").parse().unwrap();
            let e = s.options.reader("x", &["lambda"]).ranged(&L).unwrap_err();
            assert!(
                e.to_string()
                    .contains("a distance from 0.001 to 1000000000"),
                "{e}"
            );
        }
    }

    #[test]
    fn flags_and_choices_name_what_they_take() {
        let s: MethodSpec = "x:on=yes:variant=abc".parse().unwrap();
        let r = s.options.reader("x", &["on", "variant"]);
        assert!(
            r.flag("on", false)
                .unwrap_err()
                .to_string()
                .contains("true or false")
        );
        let e = r.choice("variant", &["fme", "fmc", "fse"]).unwrap_err();
        assert!(
            e.to_string()
                .ends_with("must be fme, fmc or fse, got 'abc'"),
            "{e}"
        );
        let none = MethodOptions::new();
        assert_eq!(
            none.reader("x", &["variant"])
                .choice("variant", &["fme", "fse"]),
            Ok("fme")
        );
    }
}
