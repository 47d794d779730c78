//! Errors of the URDF loader: each names the file, and where it can, the line and the element.

use std::path::PathBuf;

/// Why a URDF was rejected.
#[derive(Debug, thiserror::Error)]
pub enum UrdfError {
    /// The file could not be read.
    #[error("{file}: cannot read URDF: {source}")]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The text is not well-formed XML.
    #[error("{file}:{line}:{column}: malformed XML: {message}")]
    Xml { file: PathBuf, line: u32, column: u32, message: String },
    /// Well-formed XML that does not follow the URDF schema (urdf-rs' message).
    #[error("{file}: not a valid URDF document: {message}")]
    Schema { file: PathBuf, message: String },
    /// A URDF element whose content is inconsistent or unsupported.
    #[error("{file}:{line}: <{element} name=\"{name}\">: {problem}")]
    Element { file: PathBuf, line: u32, element: &'static str, name: String, problem: String },
}

impl UrdfError {
    /// The element this error is about (`link`, `joint`, ...), when it names one.
    pub fn element(&self) -> Option<&'static str> {
        match self {
            UrdfError::Element { element, .. } => Some(element),
            _ => None,
        }
    }
}
