//! Naming a method and its knobs: `occlusion_tree:k=32:variant=fme` on the
//! command line, `{"method": "occlusion_tree", "options": {"k": 32}}` in JSON.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// Every method name of DESIGN's contract, whether or not a scene supports it.
pub const METHOD_NAMES: [&str; 7] = [
    "frustum",
    "occlusion_tree",
    "supporting_planes",
    "horizon",
    "ddo",
    "gpu",
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
    /// The value of `key` parsed as `T`, or `default` when absent.
    pub fn get<T: FromStr>(
        &self,
        key: &'static str,
        default: T,
        expected: &str,
    ) -> Result<T, MethodError> {
        debug_assert!(self.known.contains(&key), "{key} is not declared");
        match self.options.0.get(key) {
            None => Ok(default),
            Some(v) => v.parse().map_err(|_| MethodError::InvalidOption {
                method: self.method.into(),
                option: key.into(),
                value: v.clone(),
                expected: expected.into(),
            }),
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

impl MethodSpec {
    /// A spec with no options.
    pub fn named(name: &str) -> Result<Self, MethodError> {
        if !METHOD_NAMES.contains(&name) {
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
        let e = "octree".parse::<MethodSpec>().unwrap_err();
        assert!(e.to_string().starts_with("unknown method 'octree'"), "{e}");
        let e = "frustum:k".parse::<MethodSpec>().unwrap_err();
        assert!(e.to_string().contains("'k' is not key=value"), "{e}");
        let s: MethodSpec = "frustum:k=3".parse().unwrap();
        let e = s.options.reader("frustum", &[]).finish().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown option 'k' for method 'frustum'; it takes no options"
        );
    }

    #[test]
    fn reader_parses_values() {
        let s: MethodSpec = "occlusion_tree:k=abc".parse().unwrap();
        let r = s.options.reader("occlusion_tree", &["k"]);
        let e = r.get::<u32>("k", 8, "a whole number").unwrap_err();
        assert_eq!(
            e.to_string(),
            "option 'k' of method 'occlusion_tree' must be a whole number, got 'abc'"
        );
        let s: MethodSpec = "occlusion_tree".parse().unwrap();
        assert_eq!(
            s.options
                .reader("occlusion_tree", &["k"])
                .get::<u32>("k", 8, "n")
                .unwrap(),
            8
        );
    }
}
