//! Locating and loading the ONNX Runtime shared library.

use crate::InferenceError;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The ONNX Runtime release `supermvo models fetch` installs (from the PyPI wheel).
pub const ORT_VERSION: &str = "1.31.1";

/// The cache root: `SUPERMVO_CACHE`, else `$XDG_CACHE_HOME/supermvo`, else `~/.cache/supermvo`.
pub fn cache_dir() -> PathBuf {
    if let Some(p) = std::env::var_os("SUPERMVO_CACHE").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    if let Some(p) = std::env::var_os("XDG_CACHE_HOME").filter(|p| !p.is_empty()) {
        return PathBuf::from(p).join("supermvo");
    }
    let home = std::env::var_os("HOME")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."));
    home.join(".cache").join("supermvo")
}

/// Where `supermvo models fetch onnxruntime` puts the library.
pub fn default_library_path() -> PathBuf {
    cache_dir()
        .join("onnxruntime")
        .join(ORT_VERSION)
        .join(format!("libonnxruntime.so.{ORT_VERSION}"))
}

/// The library to load: `explicit`, else `ORT_DYLIB_PATH`, else the cached copy.
pub fn resolve_library(explicit: Option<&Path>) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    match std::env::var_os("ORT_DYLIB_PATH") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => default_library_path(),
    }
}

static LOADED: OnceLock<Result<(PathBuf, ort::environment::Environment), String>> = OnceLock::new();

/// Loads ONNX Runtime once per process. Later calls return the first outcome, whatever
/// path they name (a process can hold only one runtime).
pub fn init(explicit: Option<&Path>) -> Result<PathBuf, InferenceError> {
    let path = resolve_library(explicit);
    let outcome = LOADED.get_or_init(|| {
        if !path.is_file() {
            return Err(format!("missing:{}", path.display()));
        }
        let builder = ort::init_from(&path).map_err(|e| e.to_string())?;
        let env = builder
            .with_name("supermvo")
            .build()
            .map_err(|e| e.to_string())?;
        tracing::info!("ONNX Runtime loaded from {}", path.display());
        Ok((path.clone(), env))
    });
    match outcome {
        Ok((p, _)) => Ok(p.clone()),
        Err(m) if m.starts_with("missing:") => Err(InferenceError::RuntimeMissing {
            path: PathBuf::from(&m["missing:".len()..]),
            wanted: ORT_VERSION,
        }),
        Err(m) => Err(InferenceError::RuntimeLoad {
            path,
            message: m.clone(),
            wanted: ORT_VERSION,
        }),
    }
}

/// Opens an ONNX model with `threads` intra-op threads, checking its input and output names.
pub fn open_session(
    path: &Path,
    name: &str,
    threads: usize,
    inputs: &[&str],
    outputs: &[&str],
) -> Result<ort::session::Session, InferenceError> {
    if !path.is_file() {
        return Err(InferenceError::ModelMissing {
            path: path.to_path_buf(),
            name: name.to_string(),
        });
    }
    let env = match LOADED.get() {
        Some(Ok((_, env))) => env,
        _ => {
            init(None)?;
            match LOADED.get() {
                Some(Ok((_, env))) => env,
                _ => {
                    return Err(InferenceError::RuntimeMissing {
                        path: resolve_library(None),
                        wanted: ORT_VERSION,
                    })
                }
            }
        }
    };
    let corrupt = |e: ort::Error| InferenceError::ModelCorrupt {
        path: path.to_path_buf(),
        name: name.to_string(),
        message: e.to_string(),
    };
    let session = ort::session::Session::builder(env)
        .map_err(corrupt)?
        .with_intra_threads(threads.max(1))
        .map_err(|e| corrupt(e.into()))?
        .with_inter_threads(1)
        .map_err(|e| corrupt(e.into()))?
        .commit_from_file(path)
        .map_err(corrupt)?;
    let found_in: Vec<String> = session
        .inputs()
        .iter()
        .map(|o| o.name().to_string())
        .collect();
    let found_out: Vec<String> = session
        .outputs()
        .iter()
        .map(|o| o.name().to_string())
        .collect();
    let ok = inputs.iter().all(|i| found_in.iter().any(|f| f == i))
        && outputs.iter().all(|o| found_out.iter().any(|f| f == o));
    if !ok {
        return Err(InferenceError::ModelInterface {
            path: path.to_path_buf(),
            name: name.to_string(),
            expected: format!("inputs {inputs:?}, outputs {outputs:?}"),
            found: format!("inputs {found_in:?}, outputs {found_out:?}"),
        });
    }
    Ok(session)
}
