//! Errors in user input (scene files and command-line options): one paragraph that names the
//! file, the key and the line, says what is wrong and how to fix it (`docs/outputs.md`).

use std::fmt;
use std::path::PathBuf;

/// What class of bad input an [`InputError`] is (the classes of `docs/outputs.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputErrorKind {
    /// The file does not exist or cannot be read.
    FileMissing,
    /// The TOML (or JSON) text does not parse.
    Syntax,
    /// A key that the format does not know (often a typo).
    UnknownKey,
    /// A required key is absent.
    MissingKey,
    /// A value has the wrong type or length.
    WrongType,
    /// A number is out of range: negative mass, μ < 0, h ≤ 0, NaN, inertia not positive
    /// definite, and so on.
    InvalidValue,
    /// The geometry is unusable: a degenerate or flat hull, a body starting inside an obstacle.
    Geometry,
    /// An unknown solver or formulation name, or one that is not available in this build.
    UnknownName,
    /// A load expression that does not parse or is not finite.
    Expression,
    /// A mesh file that cannot be read.
    Mesh,
}

impl InputErrorKind {
    /// A short label for the error class.
    pub fn as_str(&self) -> &'static str {
        match self {
            InputErrorKind::FileMissing => "file missing",
            InputErrorKind::Syntax => "syntax error",
            InputErrorKind::UnknownKey => "unknown key",
            InputErrorKind::MissingKey => "missing key",
            InputErrorKind::WrongType => "wrong type",
            InputErrorKind::InvalidValue => "invalid value",
            InputErrorKind::Geometry => "invalid geometry",
            InputErrorKind::UnknownName => "unknown name",
            InputErrorKind::Expression => "invalid expression",
            InputErrorKind::Mesh => "invalid mesh",
        }
    }
}

/// Bad user input. Displayed as one paragraph:
/// `scenes/x.toml, line 7, key bodies[0].mass: invalid value: ...`.
#[derive(Clone, Debug, PartialEq)]
pub struct InputError {
    /// The file the input came from (`None` for command-line options).
    pub file: Option<PathBuf>,
    /// The key path, e.g. `bodies[0].mass` (or the command-line option).
    pub key: Option<String>,
    /// 1-based line in the file, where there is one.
    pub line: Option<usize>,
    /// The class of error.
    pub kind: InputErrorKind,
    /// What is wrong and how to fix it.
    pub message: String,
}

impl InputError {
    /// An error about a command-line option (no file).
    pub fn option(option: &str, kind: InputErrorKind, message: impl Into<String>) -> Self {
        InputError {
            file: None,
            key: Some(option.to_string()),
            line: None,
            kind,
            message: message.into(),
        }
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut wrote = false;
        if let Some(file) = &self.file {
            write!(f, "{}", file.display())?;
            wrote = true;
        }
        if let Some(line) = self.line {
            write!(f, "{}line {line}", if wrote { ", " } else { "" })?;
            wrote = true;
        }
        if let Some(key) = &self.key {
            let what = if self.file.is_some() { "key" } else { "option" };
            write!(f, "{}{what} `{key}`", if wrote { ", " } else { "" })?;
            wrote = true;
        }
        if wrote {
            f.write_str(": ")?;
        }
        write!(f, "{}: {}", self.kind.as_str(), self.message)
    }
}

impl std::error::Error for InputError {}
