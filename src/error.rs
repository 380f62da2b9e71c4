//! The library's top-level error: each layer's typed error, kept with its cause.

/// Any error of a vkinverse operation.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
    #[error(transparent)]
    Image(#[from] crate::image::ImageError),
    #[error(transparent)]
    Npy(#[from] crate::npy::NpyError),
    #[error(transparent)]
    Optim(#[from] crate::optim::OptimError),
    #[error("{path}: {source}")]
    Io { path: std::path::PathBuf, source: std::io::Error },
    #[error("{0}")]
    Invalid(String),
    /// The work was cancelled ([`crate::Cancel`]); the message says what was left.
    #[error("interrupted: {0}")]
    Interrupted(String),
    /// The validation layer ([`crate::Config::validation`]) reported something during the
    /// call: a bug of vkinverse or of the driver.
    #[error("the Vulkan validation layer reported {count} message(s); the first: {first}")]
    Validation { count: usize, first: String },
}

pub type Result<T> = std::result::Result<T, Error>;

/// The error and its causes as one line. The library's errors quote their cause already;
/// a `source()` they do not quote is appended after a colon. A multi-line cause (toml's
/// annotated snippet) is left out: the layer above has put its gist on its own line.
pub fn one_line(e: &dyn std::error::Error) -> String {
    let mut msg = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !text.contains('\n') && !msg.contains(&text) {
            msg = format!("{msg}: {text}");
        }
        cause = c.source();
    }
    msg.lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join("; ")
}
