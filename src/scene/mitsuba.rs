//! Importer (in progress).
use std::path::Path;

use super::loader::Imported;
use super::SceneError;

pub(super) fn import(path: &Path) -> Result<Imported, SceneError> {
    Err(SceneError::Invalid { scene: path.to_path_buf(), key: String::new(), message: "not supported".into() })
}
