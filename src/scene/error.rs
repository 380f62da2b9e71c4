//! `SceneError`: everything that can be wrong with a scene, each message one line that
//! names the file and the key (`materials.wall.roughness`) or line (`scene.toml:12:5`).

use std::io;
use std::path::PathBuf;

use thiserror::Error;

use crate::image::ImageError;

#[derive(Debug, Error)]
pub enum SceneError {
    /// The scene file itself cannot be read.
    #[error("{}: cannot read scene: {source}", path.display())]
    ReadScene { path: PathBuf, source: io::Error },

    /// TOML syntax, an unknown key, a missing key or a value of the wrong type.
    #[error("{}:{line}:{column}: {message}", path.display())]
    Toml { path: PathBuf, line: usize, column: usize, message: String, source: Box<toml::de::Error> },

    /// A file named by `key` cannot be read.
    #[error("{}: {key}: cannot read {}: {source}", scene.display(), file.display())]
    MissingFile { scene: PathBuf, key: String, file: PathBuf, source: io::Error },

    /// A mesh file (OBJ or PLY) is malformed; `line` is 0 where no single line is at fault.
    #[error("{}{}: {message}", path.display(), if *line > 0 { format!(":{line}") } else { String::new() })]
    Obj { path: PathBuf, line: usize, message: String },

    /// tobj rejected an OBJ file that passed the line checks.
    #[error("{}: malformed OBJ: {source}", path.display())]
    ObjParse { path: PathBuf, source: tobj::LoadError },

    /// An image named by `key` cannot be decoded.
    #[error("{}: {key}: {source}", scene.display())]
    Image { scene: PathBuf, key: String, source: ImageError },

    #[error("{}: {key}: {} has a non-finite value at pixel ({x}, {y})", scene.display(), image.display())]
    NonFinitePixel { scene: PathBuf, key: String, image: PathBuf, x: u32, y: u32 },

    #[error("{}: {key}: non-finite value", scene.display())]
    NonFinite { scene: PathBuf, key: String },

    /// A value outside what it may be (film size, field of view, init outside range, ...).
    #[error("{}: {key}: {message}", scene.display())]
    OutOfRange { scene: PathBuf, key: String, message: String },

    /// `key` refers to a material or mesh that the scene does not define; `known` lists
    /// the names of that kind that it does ([`known_names`]).
    #[error("{}: {key}: no {kind} named \"{name}\" ({known})", scene.display())]
    Undefined { scene: PathBuf, key: String, kind: &'static str, name: String, known: String },

    #[error("{}: {key}: \"{name}\" is defined more than once", scene.display())]
    Duplicate { scene: PathBuf, key: String, name: String },

    /// A glTF or Mitsuba file that cannot be imported: `location` is a JSON path
    /// (`materials[2].normalTexture`) or an XML line and element (`line 14: <bsdf
    /// type="plastic">`), or empty when the whole file is at fault.
    #[error("{}: {}{message}", path.display(), if location.is_empty() { String::new() } else { format!("{location}: ") })]
    Import { path: PathBuf, location: String, message: String },

    /// The recovered scene could not be written.
    #[error("{}: cannot write the recovered scene: {message}", path.display())]
    Write { path: PathBuf, message: String },

    /// Any other inconsistency between keys.
    #[error("{}: {key}: {message}", scene.display())]
    Invalid { scene: PathBuf, key: String, message: String },
}

impl SceneError {
    /// One-line error from toml's, whose own Display spans several lines.
    pub(crate) fn toml(path: PathBuf, text: &str, source: toml::de::Error) -> Self {
        let mut offset = source.span().map_or(0, |s| s.start.min(text.len()));
        while !text.is_char_boundary(offset) {
            offset -= 1;
        }
        let before = &text[..offset];
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        let message = match source.message().trim() {
            // toml's error for a value cut short names no problem.
            "" if offset >= text.trim_end().len() => "the file ends where a value should be".to_string(),
            "" => "malformed TOML here".to_string(),
            m => m.replace('\n', "; "),
        };
        Self::Toml { path, line, column, message, source: Box::new(source) }
    }
}

/// "the scene has NAME, NAME, ..." for an error about a name that is not there (the first
/// 12, then how many more), or "the scene has none".
pub fn known_names<'a>(names: impl IntoIterator<Item = &'a str>) -> String {
    let names: Vec<String> = names.into_iter().map(|n| format!("\"{n}\"")).collect();
    match names.len() {
        0 => "the scene has none".into(),
        n if n <= 12 => format!("the scene has {}", names.join(", ")),
        n => format!("the scene has {} and {} more", names[..12].join(", "), n - 12),
    }
}
