use std::path::PathBuf;

/// Errors of the learned front end; each says what to run or change.
#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    /// The ONNX Runtime library is not where we looked.
    #[error("ONNX Runtime library not found at {path}; run 'supermvo models fetch onnxruntime' or set ORT_DYLIB_PATH to libonnxruntime.so (version {wanted} or newer)")]
    RuntimeMissing {
        /// Where we looked.
        path: PathBuf,
        /// Version we need.
        wanted: &'static str,
    },
    /// The library exists but could not be used (not ONNX Runtime, or too old).
    #[error("cannot use ONNX Runtime at {path}: {message}; run 'supermvo models fetch onnxruntime' (installs {wanted}) or point ORT_DYLIB_PATH at a matching library")]
    RuntimeLoad {
        /// Library path.
        path: PathBuf,
        /// What went wrong.
        message: String,
        /// Version we need.
        wanted: &'static str,
    },
    /// A model file is missing.
    #[error("model file {path} not found; run 'supermvo models fetch {name}{}'", weights_hint(.name))]
    ModelMissing {
        /// Expected path.
        path: PathBuf,
        /// Model name to fetch.
        name: String,
    },
    /// A model file exists but ONNX Runtime cannot load it.
    #[error("model file {path} is corrupt or not an ONNX model ({message}); delete it and run 'supermvo models fetch {name}'")]
    ModelCorrupt {
        /// Model path.
        path: PathBuf,
        /// Model name to fetch.
        name: String,
        /// Loader message.
        message: String,
    },
    /// A model whose inputs or outputs are not what this front end expects.
    #[error("model {path} does not have the interface of {name}: expected {expected}, found {found}; is it the right file?")]
    ModelInterface {
        /// Model path.
        path: PathBuf,
        /// Model name.
        name: String,
        /// Expected inputs/outputs.
        expected: String,
        /// Actual inputs/outputs.
        found: String,
    },
    /// The input image cannot be processed.
    #[error("bad input image: {0}")]
    BadImage(String),
    /// ONNX Runtime failed while running a model.
    #[error("ONNX Runtime failed running {model}: {message}")]
    Run {
        /// Model name.
        model: String,
        /// Runtime message.
        message: String,
    },
}

/// What `supermvo models fetch NAME` needs besides the name: the local weights file for the
/// models whose official weights cannot be downloaded.
fn weights_hint(name: &str) -> &'static str {
    match name {
        "superpoint" => " --weights /path/to/superpoint_v1.pth",
        "superglue" => " --weights /path/to/superglue_outdoor.pth",
        _ => "",
    }
}
