"""Build the Blender extension zip: dist/gaussian_splatting-<version>.zip.

    .venv/bin/python scripts/build_extension.py [--out DIR] [--wheel-dir DIR]

1. `pip wheel native/` builds the native module `splatcore` as one cp311-abi3 wheel for this
   platform (it loads in every Blender from 4.2, Python 3.11, to 5.x).
2. The zip gets, at its root (Blender expects the add-on's `__init__.py` there):
   - `blender_manifest.toml`: the repository's, with `wheels` listing the wheel it holds and
     `platforms` the platform that wheel is for;
   - the add-on package, i.e. the contents of `addon/` (`__init__.py`, `core/`, `blender/`),
     without caches;
   - `wheels/splatcore-<version>-cp311-abi3-<platform>.whl`.

Blender installs it like any extension (Preferences > Get Extensions > Install from Disk, or
`blender --command extension install-file -r user_default -e FILE.zip`, or
`bpy.ops.extensions.package_install_files(filepath=..., repo="user_default",
enable_on_install=True)`), installing the wheel into its private site-packages.
Everything else the add-on uses ships with Blender (numpy, OpenImageIO, zstandard); pycolmap
(COLMAP import only) is not bundled.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# wheel platform tag -> Blender manifest platform
_PLATFORMS = {
    "linux_x86_64": "linux-x64", "manylinux": "linux-x64", "linux_aarch64": "linux-arm64",
    "win_amd64": "windows-x64", "win_arm64": "windows-arm64",
    "macosx_arm64": "macos-arm64", "macosx_x86_64": "macos-x64",
}


def build_wheel(wheel_dir: Path) -> Path:
    wheel_dir.mkdir(parents=True, exist_ok=True)
    for old in wheel_dir.glob("splatcore-*.whl"):
        old.unlink()
    with tempfile.TemporaryDirectory() as scratch:  # keep build/ out of native/
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                        "--no-build-isolation", "-w", str(wheel_dir), str(ROOT / "native")],
                       check=True, cwd=scratch)
    wheels = sorted(wheel_dir.glob("splatcore-*.whl"))
    if len(wheels) != 1:
        raise RuntimeError(f"expected one splatcore wheel in {wheel_dir}, found {wheels}")
    return wheels[0]


def platform_of(wheel: Path) -> str:
    tag = wheel.stem.split("-")[-1]
    for prefix, platform in _PLATFORMS.items():
        if tag.startswith(prefix) or (prefix in ("macosx_arm64", "macosx_x86_64")
                                      and tag.startswith("macosx") and tag.endswith(prefix[7:])):
            return platform
    raise RuntimeError(f"unknown wheel platform tag {tag!r}")


def manifest_for(wheel: Path) -> tuple[str, str]:
    """The manifest text with `wheels` (and `platforms`) set for `wheel`; the version."""
    text = (ROOT / "blender_manifest.toml").read_text()
    version = re.search(r'^version\s*=\s*"([^"]+)"', text, re.M).group(1)
    text = re.sub(r"^#?\s*wheels\s*=.*$\n?", "", text, flags=re.M)
    text = re.sub(r"^platforms\s*=.*$\n?", "", text, flags=re.M)
    lines = [f'wheels = ["./wheels/{wheel.name}"]', f'platforms = ["{platform_of(wheel)}"]']
    head, sep, tail = text.partition("\n[")  # top-level keys go before the first table
    text = head.rstrip() + "\n" + "\n".join(lines) + "\n" + (sep + tail if sep else "")
    return text, version


def build_zip(out_dir: Path, wheel: Path) -> Path:
    manifest, version = manifest_for(wheel)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"gaussian_splatting-{version}.zip"
    package = ROOT / "addon"
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("blender_manifest.toml", manifest)
        for path in sorted(package.rglob("*")):
            relative = path.relative_to(package)
            if path.is_dir() or "__pycache__" in relative.parts or path.suffix in (".pyc", ".so"):
                continue
            archive.write(path, relative.as_posix())
        archive.write(wheel, f"wheels/{wheel.name}")
    return target


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "dist"))
    parser.add_argument("--wheel-dir", default=str(ROOT / "build" / "wheels"))
    args = parser.parse_args()
    wheel = build_wheel(Path(args.wheel_dir))
    target = build_zip(Path(args.out), wheel)
    print(f"{target} ({target.stat().st_size / 1e6:.1f} MB) with {wheel.name}")


if __name__ == "__main__":
    main()
