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

/// Where the networks run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Device {
    /// ONNX Runtime's CPU execution provider.
    #[default]
    Cpu,
    /// ONNX Runtime's CUDA execution provider (the `onnxruntime-gpu` build and an NVIDIA GPU
    /// with CUDA 13 and cuDNN 9 libraries); sessions fall back to the CPU, with a warning,
    /// where it cannot be used.
    Cuda,
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Device::Cpu => "CPU",
            Device::Cuda => "CUDA",
        })
    }
}

/// Where `supermvo models fetch onnxruntime` puts the library.
pub fn default_library_path() -> PathBuf {
    cache_dir()
        .join("onnxruntime")
        .join(ORT_VERSION)
        .join(format!("libonnxruntime.so.{ORT_VERSION}"))
}

/// Where `supermvo models fetch onnxruntime-gpu` puts the GPU build of the library.
pub fn gpu_library_path() -> PathBuf {
    cache_dir()
        .join("onnxruntime-gpu")
        .join(ORT_VERSION)
        .join(format!("libonnxruntime.so.{ORT_VERSION}"))
}

/// The library to load: `explicit`, else `ORT_DYLIB_PATH`, else the cached copy.
pub fn resolve_library(explicit: Option<&Path>) -> PathBuf {
    resolve_library_for(explicit, Device::Cpu)
}

/// As [`resolve_library`], preferring the cached GPU build when `device` is CUDA and it has
/// been fetched.
pub fn resolve_library_for(explicit: Option<&Path>, device: Device) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    match std::env::var_os("ORT_DYLIB_PATH") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ if device == Device::Cuda && gpu_library_path().is_file() => gpu_library_path(),
        _ => default_library_path(),
    }
}

static LOADED: OnceLock<Result<(PathBuf, ort::environment::Environment), String>> = OnceLock::new();

/// Loads ONNX Runtime once per process. Later calls return the first outcome, whatever
/// path they name (a process can hold only one runtime).
pub fn init(explicit: Option<&Path>) -> Result<PathBuf, InferenceError> {
    init_for(explicit, Device::Cpu)
}

/// As [`init`], choosing the library for `device` (see [`resolve_library_for`]).
pub fn init_for(explicit: Option<&Path>, device: Device) -> Result<PathBuf, InferenceError> {
    let path = resolve_library_for(explicit, device);
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

/// Opens an ONNX model on the CPU with `threads` intra-op threads, checking its input and
/// output names.
pub fn open_session(
    path: &Path,
    name: &str,
    threads: usize,
    inputs: &[&str],
    outputs: &[&str],
) -> Result<ort::session::Session, InferenceError> {
    open_session_on(path, name, (threads, false), Device::Cpu, inputs, outputs).map(|(s, _)| s)
}

/// Registers the CUDA execution provider on `builder`, or says why it cannot be used.
fn with_cuda(
    builder: ort::session::builder::SessionBuilder,
) -> (ort::session::builder::SessionBuilder, Result<(), String>) {
    use ort::ep::ExecutionProvider;
    match ort::ep::CUDA::is_available() {
        Ok(true) => {}
        Ok(false) => {
            return (
                builder,
                Err(format!(
                    "the ONNX Runtime at {} was built without it (run 'supermvo models fetch onnxruntime-gpu')",
                    loaded_library().display()
                )),
            )
        }
        Err(e) => return (builder, Err(e.to_string())),
    }
    match builder.with_execution_providers([ort::ep::CUDA::default().build().error_on_failure()]) {
        Ok(b) => (b, Ok(())),
        Err(e) => {
            let message = format!(
                "{} (it needs an NVIDIA GPU and the CUDA 13 and cuDNN 9 libraries on the library path)",
                e.to_string().trim_end()
            );
            (e.recover(), Err(message))
        }
    }
}

/// The library [`init`] loaded (or would load).
fn loaded_library() -> PathBuf {
    match LOADED.get() {
        Some(Ok((p, _))) => p.clone(),
        _ => resolve_library(None),
    }
}

/// Opens an ONNX model on `device` (CUDA falls back to the CPU, with a warning naming the
/// reason, where it cannot be used) with `threads` intra-op threads that spin between calls
/// when `spin` is set, checking its input and output names. Returns the session and the
/// device it runs on.
///
/// Spinning keeps a session's threads busy-waiting for a while after each call. Where two
/// networks alternate on the same cores (extraction then matching, in one process or in two
/// stage processes) the idle session's spinning threads take the cores the running one needs:
/// `tools/bench_spinning.py` measures both settings.
pub fn open_session_on(
    path: &Path,
    name: &str,
    (threads, spin): (usize, bool),
    device: Device,
    inputs: &[&str],
    outputs: &[&str],
) -> Result<(ort::session::Session, Device), InferenceError> {
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
    let builder = ort::session::Session::builder(env)
        .map_err(corrupt)?
        .with_intra_threads(threads.max(1))
        .map_err(|e| corrupt(e.into()))?
        .with_inter_threads(1)
        .map_err(|e| corrupt(e.into()))?
        .with_intra_op_spinning(spin)
        .map_err(|e| corrupt(e.into()))?
        // Subnormal floats (the far tails of the attention softmax) are 10-50x slower on
        // x86; flushing them to zero halved LighterGlue's time with the same matches.
        .with_flush_to_zero()
        .map_err(|e| corrupt(e.into()))?;
    let (mut builder, used) = match device {
        Device::Cpu => (builder, Device::Cpu),
        Device::Cuda => match with_cuda(builder) {
            (b, Ok(())) => (b, Device::Cuda),
            (b, Err(why)) => {
                tracing::warn!(
                    "{name}: CUDA was asked for but cannot be used: {why}; running on the CPU"
                );
                (b, Device::Cpu)
            }
        },
    };
    let session = builder.commit_from_file(path).map_err(corrupt)?;
    match used {
        Device::Cpu => tracing::info!(
            "{name}: running on the CPU ({} intra-op threads, spinning {})",
            threads.max(1),
            if spin { "on" } else { "off" }
        ),
        Device::Cuda => tracing::info!("{name}: running on CUDA (device 0)"),
    }
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
    Ok((session, used))
}
