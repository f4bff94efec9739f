"""Read PyTorch checkpoints into NumPy arrays without importing torch: the zip format
(torch >= 1.6) and the legacy format before it (a magic number, then pickles, then the raw
storages), which older published weights such as MagicLeap's SuperPoint/SuperGlue use.

A restricted unpickler: only the classes a plain state dict needs (OrderedDict, the tensor
rebuild helpers and the typed storages) may be loaded; anything else raises, so a
malicious checkpoint cannot run code.
"""
import collections
import pickle
import zipfile

import numpy as np

_STORAGE_DTYPES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
}


class _StorageType:
    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)


class _LegacyStorage:
    """A storage of the legacy format: its bytes follow the pickles, so tensors wait for it."""

    def __init__(self, dtype, numel):
        self.dtype, self.numel, self.data = np.dtype(dtype), numel, None


class _Pending:
    def __init__(self, storage, args):
        self.storage, self.args = storage, args

    def resolve(self):
        return _rebuild_tensor_v2(self.storage.data, *self.args)


def _rebuild_tensor_v2(storage, offset, size, stride, requires_grad=False, backward_hooks=None, metadata=None):
    if isinstance(storage, _LegacyStorage):
        return _Pending(storage, (offset, size, stride))
    itemsize = storage.dtype.itemsize
    if len(size) == 0:
        return np.array(storage[offset])
    view = np.lib.stride_tricks.as_strided(storage[offset:], shape=tuple(size),
                                           strides=tuple(s * itemsize for s in stride))
    return np.ascontiguousarray(view)


def _rebuild_parameter(data, requires_grad=False, backward_hooks=None):
    return data


class _Unpickler(pickle.Unpickler):
    def __init__(self, fileobj, archive, prefix):
        super().__init__(fileobj)
        self._archive = archive
        self._prefix = prefix

    def find_class(self, module, name):
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor_v2
        if (module, name) == ("torch._utils", "_rebuild_parameter"):
            return _rebuild_parameter
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(_STORAGE_DTYPES[name])
        raise pickle.UnpicklingError(f"checkpoint refers to {module}.{name}, which a weights file must not need")

    def persistent_load(self, pid):
        kind, storage_type, key, _location, numel = pid
        if kind != "storage" or not isinstance(storage_type, _StorageType):
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r}")
        raw = self._archive.read(f"{self._prefix}/data/{key}")
        return np.frombuffer(raw, dtype=storage_type.dtype, count=numel)


class _LegacyUnpickler(_Unpickler):
    def __init__(self, fileobj, storages):
        pickle.Unpickler.__init__(self, fileobj)
        self._storages = storages

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage" and isinstance(pid[1], _StorageType)):
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r}")
        _kind, storage_type, key, _location, numel = pid[:5]
        if key not in self._storages:
            self._storages[key] = _LegacyStorage(storage_type.dtype, numel)
        return self._storages[key]


_LEGACY_MAGIC = 0x1950A86A20F9469CFC6C


def _load_legacy(path):
    storages = {}
    with open(path, "rb") as f:
        plain = _LegacyUnpickler(f, storages)
        if plain.load() != _LEGACY_MAGIC:
            raise ValueError(f"{path}: not a PyTorch checkpoint (neither zip nor legacy format)")
        plain.load()  # protocol version
        plain.load()  # system info
        obj = _LegacyUnpickler(f, storages).load()
        keys = _LegacyUnpickler(f, storages).load()
        for key in keys:
            st = storages[key]
            numel = int.from_bytes(f.read(8), "little")
            raw = f.read(numel * st.dtype.itemsize)
            if numel != st.numel or len(raw) != numel * st.dtype.itemsize:
                raise ValueError(f"{path}: storage {key} is truncated or inconsistent")
            st.data = np.frombuffer(raw, dtype=st.dtype)
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: expected a state dict, found {type(obj).__name__}")
    return {k: v.resolve() if isinstance(v, _Pending) else v for k, v in obj.items()}


def load_state_dict(path):
    """Returns {name: np.ndarray} of a torch.save()d state dict."""
    if not zipfile.is_zipfile(path):
        return {k: np.asarray(v) for k, v in _load_legacy(path).items()}
    with zipfile.ZipFile(path) as z:
        pkl = [n for n in z.namelist() if n.endswith("/data.pkl")]
        if len(pkl) != 1:
            raise ValueError(f"{path}: not a PyTorch zip checkpoint (no unique data.pkl)")
        prefix = pkl[0][: -len("/data.pkl")]
        with z.open(pkl[0]) as f:
            obj = _Unpickler(f, z, prefix).load()
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: expected a state dict, found {type(obj).__name__}")
    return {k: np.asarray(v) for k, v in obj.items()}
