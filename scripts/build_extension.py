"""Build the Blender extension: one zip per platform, carrying every wheel the add-on needs.

    .venv/bin/python scripts/build_extension.py                       # every platform, into dist/
    .venv/bin/python scripts/build_extension.py --platform linux-x64  # one (repeatable)
    options: --out DIR, --python 3.11 (repeatable: only these Pythons' wheels), --cache DIR,
             --refresh (forget cached downloads and known-missing wheels)

Each zip, `dist/gaussian_splatting-<version>-<platform>.zip` with `-` in the platform written
`_` (the name `blender --command extension build --split-platforms` gives), holds at its root:
  - `blender_manifest.toml`: the repository's, plus `platforms = ["<platform>"]` and `wheels`
    listing every wheel in the zip;
  - the add-on package (the contents of `addon/`, without caches);
  - `wheels/`: the native module `splatcore` (one cp311-abi3 wheel from
    `scripts/build_native.py`) and, for each Python in PYTHONS, the wheels of the modules the add-on
    imports that Blender does not guarantee (BUNDLED). Blender installs only the wheels matching
    its platform and Python (bl_pkg's `_extensions_wheel_filter_for_this_system`: same platform
    tag, any manylinux of the same architecture, any macOS version of the same architecture; the
    same CPython minor, or an older abi3) into the extension's site-packages, which goes on
    sys.path before Blender's own site-packages.

Blender derives the Pythons an extension supports from its wheels' tags (`python_versions_from_
wheels`): with cp311/cp313/cp314 wheels inside, Blender refuses the zip on any other Python, so a
Python is listed in PYTHONS only when the zip really works there.

Wheels come from PyPI with `pip download --only-binary=:all: --platform ... --python-version ...`
and are cached (default ~/.cache/gaussian-splatting/wheels, shared by checkouts and CI runs); a
wheel PyPI does not have is remembered as missing, printed in the build's table, and the add-on
reports the missing module when the feature that needs it is used.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from build_native import build_native_wheel  # noqa: E402 - next to this script

ROOT = Path(__file__).resolve().parent.parent

# Blender 4.2 - 5.0 run Python 3.11, 5.1 and later 3.13; Debian's Blender 5.2 runs 3.14.
PYTHONS = ("3.11", "3.13", "3.14")

# What the add-on imports beyond the standard library, numpy (every Blender has it: official
# builds bundle it, distributions depend on it) and bpy's own modules, and Blender does not
# guarantee (checked against the bpy wheels 4.2 / 4.5 / 5.0 and Debian's Blender 4.3 / 5.2):
#   pycolmap     COLMAP import, training     in no Blender
#   OpenImageIO  EXR/PNG, SOG's WebP         official builds bundle it; the bpy wheels keep it
#                                            off sys.path (5.0) or lack it (4.2); Debian lacks it
#   xatlas       Convert to Mesh (UV atlas)  in no Blender
#   zstandard    .spz version 4              official builds and bpy's dependencies; not Debian
#   av           video frames for            in no Blender (PyAV: FFmpeg inside, one abi3
#                Import Photos or Video      wheel per platform)
# Versions are requirements.txt's pins (tested there), except where a pin has no wheel for a
# Python: OVERRIDES names the version used for it.
BUNDLED = ("pycolmap", "OpenImageIO", "xatlas", "zstandard", "av")
OVERRIDES = {("openimageio", "3.14"): "3.1.19.0"}  # the 3.0 line publishes no cp314 wheels
# Wheels of use only beside another: videos are read only to reconstruct, which needs pycolmap
# (no zip carries 34 MB of FFmpeg that nothing can use).
ONLY_WITH = {"av": "pycolmap"}


@dataclass(frozen=True)
class Platform:
    """A Blender platform and the pip platform tags that fit it: `tags` what every Blender
    there runs on; `newer_tags` (tried when `tags` has no wheel) needs a newer OS."""
    name: str
    tags: tuple[str, ...]
    newer_tags: tuple[str, ...] = ()


def _manylinux(arch: str) -> tuple[str, ...]:
    # Blender 4.2+ Linux builds need glibc 2.28, so any manylinux up to 2_28 loads there.
    return (*(f"manylinux_2_{minor}_{arch}" for minor in range(28, 16, -1)),
            f"manylinux2014_{arch}")


# pip expands a macosx_X_Y tag to every older macOS; Blender 4.2+ needs macOS 11.2.
PLATFORMS = {p.name: p for p in (
    Platform("linux-x64", _manylinux("x86_64")),
    Platform("linux-arm64", _manylinux("aarch64")),
    Platform("windows-x64", ("win_amd64",)),
    Platform("macos-arm64", ("macosx_11_0_arm64",), ("macosx_15_0_arm64",)),
    Platform("macos-x64", ("macosx_11_0_x86_64",), ("macosx_15_0_x86_64",)),
    Platform("windows-arm64", ("win_arm64",)),
)}
# windows-arm64 is built on request only: PyPI has no pycolmap, OpenImageIO or xatlas for it.
DEFAULT_PLATFORMS = ("linux-x64", "linux-arm64", "windows-x64", "macos-arm64", "macos-x64")


def default_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "gaussian-splatting" / "wheels"


def normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def pinned_versions() -> dict[str, str]:
    """BUNDLED's versions from requirements.txt (normalized name -> version)."""
    pins = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        match = re.match(r"^\s*([A-Za-z0-9_.-]+)\s*==\s*([^\s#;]+)", line)
        if match:
            pins[normalized(match.group(1))] = match.group(2)
    missing = [name for name in BUNDLED if normalized(name) not in pins]
    if missing:
        raise RuntimeError(f"requirements.txt pins no version of {missing}")
    return {normalized(name): pins[normalized(name)] for name in BUNDLED}


@dataclass(frozen=True)
class Fetched:
    wheel: Path | None  # None: PyPI has no wheel for this platform and Python
    note: str = ""      # e.g. "needs macOS 14.0"


def _pip_download(requirement: str, tags: tuple[str, ...], python: str, into: Path) -> Path | None:
    with tempfile.TemporaryDirectory(dir=into) as scratch:
        command = [sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check",
                   "--only-binary=:all:", "--no-deps", "--implementation", "cp",
                   "--python-version", python, "-d", scratch, requirement]
        for tag in tags:
            command[4:4] = ["--platform", tag]
        done = subprocess.run(command, capture_output=True, text=True)
        wheels = list(Path(scratch).glob("*.whl"))
        if done.returncode != 0 or len(wheels) != 1:
            not_on_pypi = ("No matching distribution", "Could not find a version")
            if any(s in done.stderr for s in not_on_pypi):
                return None
            raise RuntimeError(f"pip download {requirement} (Python {python}, {tags[0]}) failed:\n"
                               + done.stderr[-2000:])
        target = into / wheels[0].name
        os.replace(wheels[0], target)
        return target


def fetch(package: str, version: str, platform: Platform, python: str, cache: Path) -> Fetched:
    """The wheel of `package==version` for `platform` and `python`, downloaded once."""
    folder = cache / platform.name / f"cp{python.replace('.', '')}"
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{normalized(package)}-{version}-"
    cached = [p for p in folder.glob("*.whl") if p.name.lower().startswith(stem)]
    missing_marker = folder / f"{stem}missing"
    if not cached and not missing_marker.exists():
        for tags in (platform.tags, platform.newer_tags):
            if tags and (wheel := _pip_download(f"{package}=={version}", tags, python, folder)):
                cached = [wheel]
                break
        else:
            missing_marker.touch()
    if not cached:
        return Fetched(None)
    wheel = cached[0]
    macos = re.search(r"macosx_(\d+)_(\d+)_", wheel.name)
    if macos and (int(macos.group(1)), int(macos.group(2))) > (11, 2):
        return Fetched(wheel, f"needs macOS {macos.group(1)}.{macos.group(2)}")
    return Fetched(wheel)


def dependency_wheels(platform: Platform, pythons: tuple[str, ...], cache: Path
                      ) -> dict[tuple[str, str], Fetched]:
    """(package, python) -> the fetched wheel, for every BUNDLED package and Python."""
    pins = pinned_versions()
    found = {}
    for python in pythons:
        for package in BUNDLED:
            needed = ONLY_WITH.get(package)
            if needed is not None and found[needed, python].wheel is None:
                found[package, python] = Fetched(None, f"not without {needed}")
                continue
            version = OVERRIDES.get((normalized(package), python), pins[normalized(package)])
            found[package, python] = fetch(package, version, platform, python, cache)
    return found


def manifest_for(platform: str, wheel_names: list[str]) -> tuple[str, str]:
    """The repository's manifest with `platforms` and `wheels` set for one zip; the version."""
    text = (ROOT / "blender_manifest.toml").read_text()
    version = re.search(r'^version\s*=\s*"([^"]+)"', text, re.M).group(1)
    text = re.sub(r"^(wheels|platforms)\s*=.*$\n?", "", text, flags=re.M)
    wheels = ",\n".join(f'  "./wheels/{name}"' for name in wheel_names)
    lines = f'platforms = ["{platform}"]\nwheels = [\n{wheels},\n]\n'
    head, sep, tail = text.partition("\n[")  # top-level keys go before the first table
    return head.rstrip() + "\n\n" + lines + (sep + tail if sep else ""), version


def zip_name(version: str, platform: str) -> str:
    return f"gaussian_splatting-{version}-{platform.replace('-', '_')}.zip"


def build_zip(out_dir: Path, platform: str, wheels: list[Path]) -> Path:
    # One wheel a name: an abi3 wheel (splatcore, av) is fetched once per Python, each time
    # into that Python's cache folder.
    wheels = sorted({w.name: w for w in wheels}.values(), key=lambda p: p.name)
    manifest, version = manifest_for(platform, [w.name for w in wheels])
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / zip_name(version, platform)
    partial = out_dir / f".{target.name}.partial"
    package = ROOT / "addon"
    with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("blender_manifest.toml", manifest)
        for path in sorted(package.rglob("*")):
            relative = path.relative_to(package)
            if path.is_dir() or "__pycache__" in relative.parts or path.suffix in (".pyc", ".so"):
                continue
            archive.write(path, relative.as_posix())
        for wheel in wheels:  # wheels are zips already: store them
            archive.write(wheel, f"wheels/{wheel.name}", compress_type=zipfile.ZIP_STORED)
    os.replace(partial, target)
    return target


def table(found: dict[tuple[str, str], Fetched], pythons: tuple[str, ...]) -> str:
    rows = [f"    {'':<12}" + "".join(f"{'Python ' + p:<40}" for p in pythons)]
    for package in BUNDLED:
        cells = []
        for python in pythons:
            item = found[package, python]
            cell = (item.wheel.name.split("-")[1] if item.wheel is not None
                    else "left out" if item.note else "MISSING")
            cells.append(f"{cell + (' (' + item.note + ')' if item.note else ''):<40}")
        rows.append(f"    {package:<12}" + "".join(cells))
    return "\n".join(rows)


def build(platform: str, out_dir: Path, pythons: tuple[str, ...], cache: Path) -> Path:
    found = dependency_wheels(PLATFORMS[platform], pythons, cache)
    print(f"{platform}: dependencies' wheels\n{table(found, pythons)}", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        native = build_native_wheel(platform, Path(scratch))
        wheels = [native] + [f.wheel for f in found.values() if f.wheel is not None]
        target = build_zip(out_dir, platform, wheels)
    print(f"{platform}: {target} ({target.stat().st_size / 1e6:.1f} MB) with {native.name}",
          flush=True)
    return target


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORMS),
                        help=f"(repeatable; default: {', '.join(DEFAULT_PLATFORMS)})")
    parser.add_argument("--python", action="append", choices=PYTHONS,
                        help="bundle wheels for this Python only (repeatable; default: all)")
    parser.add_argument("--out", default=str(ROOT / "dist"))
    parser.add_argument("--cache", default=str(default_cache()))
    parser.add_argument("--refresh", action="store_true", help="empty the wheel cache first")
    args = parser.parse_args()
    cache = Path(args.cache)
    if args.refresh and cache.exists():
        shutil.rmtree(cache)
    pythons = tuple(args.python or PYTHONS)
    failed = []
    for platform in args.platform or DEFAULT_PLATFORMS:
        try:
            build(platform, Path(args.out), pythons, cache)
        except (NotImplementedError, RuntimeError, subprocess.CalledProcessError) as error:
            print(f"{platform}: NOT BUILT: {error}", file=sys.stderr, flush=True)
            failed.append(platform)
    if failed:
        print(f"not built: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
