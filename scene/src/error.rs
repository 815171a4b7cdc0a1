//! Errors a scene file can have, worded for the person who wrote it.

use std::fmt;

/// Why a scene could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read at all.
    #[error("{path}: cannot read scene file: {message}")]
    Io { path: String, message: String },
    /// The JSON is malformed or has the wrong shape for a scene.
    #[error("{origin}:{line}:{column}: {message}")]
    Syntax {
        origin: String,
        line: usize,
        column: usize,
        message: String,
    },
    /// The JSON is well-formed but describes an impossible scene.
    #[error("{origin}: {} problem{} in scene:\n{}", issues.len(), if issues.len() == 1 { "" } else { "s" }, IssueList(issues))]
    Invalid {
        origin: String,
        issues: Vec<SceneIssue>,
    },
}

/// One semantic problem, and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneIssue {
    /// Where: e.g. `surface #3 "floor"`, `material #0 "white"`, `lightmap`.
    pub location: String,
    /// What is wrong, e.g. `albedo[1] = 1.2 is outside [0, 1)`.
    pub problem: String,
}

impl fmt::Display for SceneIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.location, self.problem)
    }
}

struct IssueList<'a>(&'a [SceneIssue]);

impl fmt::Display for IssueList<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, issue) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "  - {issue}")?;
        }
        Ok(())
    }
}
