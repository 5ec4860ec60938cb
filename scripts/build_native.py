#!/usr/bin/env python3
"""Builds the native module `splatcore` for every platform Blender ships, from this Linux x86-64
machine, as one cp311-abi3 wheel per platform.

    python scripts/build_native.py                      # all platforms into dist/native/
    python scripts/build_native.py windows-x64 -o out/  # one platform

The compiler is Zig's `zig cc` (clang with the C libraries of every target, from the `ziglang`
PyPI package, installed here from native/build-requirements.txt when it is missing). Each
target is compiled with the same flags as native/setup.py; the CPython 3.11 limited-API headers
come from the Python running this script (they only depend on the target through pyconfig.h:
Linux and macOS are LP64 like this host; Windows gets native/platform/windows/pyconfig.h and an
import library for python3.dll generated with `zig dlltool`). See docs/development.md, "Building
the native module for other platforms", for why it is an abi3 extension rather than a ctypes library.

`build_native_wheel(platform, out_dir)` is the interface scripts/build_extension.py calls.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import importlib.util
import re
import shutil
import struct
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NATIVE = ROOT / "native"
BUILD_REQUIREMENTS = NATIVE / "build-requirements.txt"
PYTHON_TAG = "cp311"  # the limited API level module.c is written for (Py_LIMITED_API 0x030B0000)

# The flags of native/setup.py (warnings are errors; -ffp-contract=fast allows FMA;
# -fno-trapping-math lets branch-free selects vectorise), for every target.
CFLAGS = ["-std=c11", "-O3", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden",
          "-ffp-contract=fast", "-fno-math-errno", "-fno-trapping-math", "-DNDEBUG",
          "-fno-sanitize=all", "-mcpu=baseline"]


@dataclass(frozen=True)
class Target:
    zig: str        # zig's target triple (with the minimum glibc or macOS version)
    wheel_tag: str  # the wheel's platform tag (Blender matches its prefix and machine suffix)
    binary: str     # the module file name inside the wheel
    os: str         # linux, windows or macos

    @property
    def executable_suffix(self) -> str:
        return ".exe" if self.os == "windows" else ""


# Blender's platform names (blender_manifest.toml `platforms`). Minimum versions: glibc 2.17
# (manylinux2014; Blender's own Linux builds need glibc 2.28, so every Linux Blender runs loads
# it) and macOS 11.0 (Blender 4.2 and later need macOS 11.2 on both architectures).
PLATFORMS: dict[str, Target] = {
    "linux-x64": Target("x86_64-linux-gnu.2.17", "manylinux_2_17_x86_64", "splatcore.abi3.so", "linux"),
    "linux-arm64": Target("aarch64-linux-gnu.2.17", "manylinux_2_17_aarch64", "splatcore.abi3.so", "linux"),
    "windows-x64": Target("x86_64-windows-gnu", "win_amd64", "splatcore.pyd", "windows"),
    "macos-arm64": Target("aarch64-macos.11.0", "macosx_11_0_arm64", "splatcore.abi3.so", "macos"),
    "macos-x64": Target("x86_64-macos.11.0", "macosx_11_0_x86_64", "splatcore.abi3.so", "macos"),
}


def version() -> str:
    with open(NATIVE / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]["version"]


def zig() -> list[str]:
    """The `zig` command, installing the pinned ziglang wheel into this Python when missing."""
    if importlib.util.find_spec("ziglang") is None:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-r", str(BUILD_REQUIREMENTS)],
                       check=True)
    return [sys.executable, "-m", "ziglang"]


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{what} failed ({done.returncode}):\n{' '.join(command)}\n"
                           f"{done.stdout}{done.stderr}")


def python_headers(target: Target, build_dir: Path) -> Path:
    """The CPython 3.11 headers for `target`: this Python's, with Windows' pyconfig.h there."""
    if sys.version_info[:2] != (3, 11):
        raise RuntimeError(f"build_native needs Python 3.11 for the cp311 limited-API headers, "
                           f"this is {sys.version.split()[0]}")
    host = Path(sysconfig.get_paths()["include"])
    if not (host / "Python.h").is_file():
        raise RuntimeError(f"no Python.h in {host}: install the Python 3.11 development headers")
    if target.os != "windows":
        return host
    # Python.h includes "pyconfig.h" from its own folder first, so copy and replace it.
    headers = build_dir / "python-include"
    shutil.rmtree(headers, ignore_errors=True)
    shutil.copytree(host, headers)
    shutil.copyfile(NATIVE / "platform" / "windows" / "pyconfig.h", headers / "pyconfig.h")
    return headers


def compile_sources(platform: str, build_dir: Path) -> tuple[list[Path], Path]:
    """Compile native/src for `platform` into build_dir: (the library's objects, module.o)."""
    target = PLATFORMS[platform]
    build_dir.mkdir(parents=True, exist_ok=True)
    include = python_headers(target, build_dir)
    cc = [*zig(), "cc", "-target", target.zig, *CFLAGS, f"-I{NATIVE / 'include'}"]
    if target.os != "windows":
        cc.append("-fPIC")
    objects: list[Path] = []
    module = build_dir / "module.o"
    for source in sorted((NATIVE / "src").glob("*.c")):
        obj = build_dir / (source.stem + ".o")
        extra = [f"-I{include}"] if source.name == "module.c" else []
        _run([*cc, *extra, "-c", str(source), "-o", str(obj)], f"compiling {source.name} for {platform}")
        if source.name != "module.c":
            objects.append(obj)
    return objects, module


def link_command(platform: str) -> list[str]:
    """zig cc for `platform` with the system libraries the library needs (for executables too)."""
    target = PLATFORMS[platform]
    libs = ["-lm", "-lpthread"] if target.os == "linux" else []
    return [*zig(), "cc", "-target", target.zig, "-O3", *libs]


# Names the limited-API headers declare as data (PyAPI_DATA): imported without a thunk.
_DATA = re.compile(r"^(PyExc_\w+|_Py_\w+Struct|Py\w+_Type)$")


def coff_imports(obj: Path) -> list[str]:
    """The `__imp_` names a COFF object imports (its undefined external symbols)."""
    data = obj.read_bytes()
    _, _, _, table, count = struct.unpack_from("<HHIII", data, 0)
    strings = table + 18 * count
    names, i = [], 0
    while i < count:
        raw, value, section, _, storage, aux = struct.unpack_from("<8sIhHBB", data, table + 18 * i)
        if raw[:4] == b"\0\0\0\0":
            offset = struct.unpack_from("<I", raw, 4)[0]
            name = data[strings + offset:data.index(b"\0", strings + offset)].decode()
        else:
            name = raw.rstrip(b"\0").decode()
        if section == 0 and storage == 2 and value == 0 and name.startswith("__imp_"):
            names.append(name[len("__imp_"):])
        i += 1 + aux
    return sorted(set(names))


def python3_import_library(module_obj: Path, build_dir: Path) -> Path:
    """An import library for python3.dll (the stable ABI) with exactly what module.o uses."""
    names = [n for n in coff_imports(module_obj) if n.startswith(("Py", "_Py"))]
    definition = build_dir / "python3.def"
    definition.write_text("LIBRARY python3.dll\nEXPORTS\n" + "".join(
        f"    {n}{' DATA' if _DATA.match(n) else ''}\n" for n in names))
    library = build_dir / "libpython3.a"
    _run([*zig(), "dlltool", "-d", str(definition), "-l", str(library), "-m", "i386:x86-64"],
         "generating the python3.dll import library")
    return library


def link_module(platform: str, objects: list[Path], module: Path, build_dir: Path) -> Path:
    target = PLATFORMS[platform]
    out = build_dir / target.binary
    command = [*link_command(platform), "-shared", "-s", "-o", str(out), str(module),
               *map(str, objects)]
    if target.os == "windows":
        command.append(str(python3_import_library(module, build_dir)))
    elif target.os == "macos":
        # Python's symbols come from the interpreter that loads the module, as for any macOS
        # extension (distutils' `-bundle -undefined dynamic_lookup`).
        command.append("-Wl,-undefined,dynamic_lookup")
    _run(command, f"linking {target.binary} for {platform}")
    return out


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def wheel_version(module: bytes) -> str:
    """The wheel's version: the project's, with the module's hash as a local label
    (0.1.0+1a2b3c4d5e6f). Blender installs an extension's wheels by their dist-info folder name
    and keeps one it already has (`_bpy_internal/extensions/wheel_manager.py`): an update whose
    module changed under the same version kept the old module (Debian's Blender 4.3, after the
    bindings took keywords: "render_train() takes no keyword arguments")."""
    return f"{version()}+{hashlib.sha256(module).hexdigest()[:12]}"


def write_wheel(platform: str, binary: Path, out_dir: Path) -> Path:
    """A wheel holding `binary` at the top level, tagged cp311-abi3-<platform tag>."""
    target = PLATFORMS[platform]
    name, ver = "splatcore", wheel_version(binary.read_bytes())
    tag = f"{PYTHON_TAG}-abi3-{target.wheel_tag}"
    info = f"{name}-{ver}.dist-info"
    files = {
        target.binary: binary.read_bytes(),
        f"{info}/METADATA": (f"Metadata-Version: 2.1\nName: {name}\nVersion: {ver}\n"
                             "Summary: Native CPU renderer for 3D Gaussian splats (Python limited "
                             "API, abi3)\nLicense: GPL-3.0-or-later\nRequires-Python: >=3.11\n").encode(),
        f"{info}/WHEEL": (f"Wheel-Version: 1.0\nGenerator: scripts/build_native.py\n"
                          f"Root-Is-Purelib: false\nTag: {tag}\n").encode(),
    }
    record = "".join(f"{path},{_record_hash(data)},{len(data)}\n" for path, data in files.items())
    files[f"{info}/RECORD"] = (record + f"{info}/RECORD,,\n").encode()
    out_dir.mkdir(parents=True, exist_ok=True)
    wheel = out_dir / f"{name}-{ver}-{tag}.whl"
    partial = wheel.with_suffix(".partial")
    with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
        for path, data in files.items():  # fixed timestamps: the same sources give the same bytes
            entry = zipfile.ZipInfo(path, date_time=(2024, 1, 1, 0, 0, 0))
            entry.external_attr = (0o755 if path == target.binary else 0o644) << 16
            archive.writestr(entry, data, zipfile.ZIP_DEFLATED)
    partial.replace(wheel)
    return wheel


def build_native_binary(platform: str, build_dir: Path) -> tuple[Path, list[Path]]:
    """Compile and link the module for `platform` in build_dir: (module file, library objects)."""
    if platform not in PLATFORMS:
        raise ValueError(f"unknown platform {platform!r}; one of {', '.join(PLATFORMS)}")
    objects, module = compile_sources(platform, build_dir)
    return link_module(platform, objects, module, build_dir), objects


def build_native_wheel(platform: str, out_dir: Path) -> Path:
    """Build `splatcore-<version>+<module hash>-cp311-abi3-<tag>.whl` for a Blender platform name
    (linux-x64, linux-arm64, windows-x64, macos-arm64, macos-x64) into out_dir; returns its path.
    Replaces an older wheel of the same name."""
    with tempfile.TemporaryDirectory(prefix=f"splatcore-{platform}-") as scratch:
        binary, _ = build_native_binary(platform, Path(scratch))
        return write_wheel(platform, binary, Path(out_dir))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("platforms", nargs="*", metavar="PLATFORM",
                        help=f"Blender platform names: {', '.join(PLATFORMS)} (default: all)")
    parser.add_argument("-o", "--out-dir", type=Path, default=ROOT / "dist" / "native")
    args = parser.parse_args()
    for platform in args.platforms:
        if platform not in PLATFORMS:
            parser.error(f"unknown platform {platform!r}; one of {', '.join(PLATFORMS)}")
    for platform in args.platforms or PLATFORMS:
        wheel = build_native_wheel(platform, args.out_dir)
        print(f"{platform:12s} {wheel.name}  {wheel.stat().st_size / 1024:.0f} KiB")


if __name__ == "__main__":
    main()
