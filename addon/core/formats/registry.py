"""Every splat file format in one table: how a path is recognised, who reads and writes it, and
what it can hold. `splat_io`, the import/export operators, the drag-and-drop file handler and
scripts all choose through `format_for(path)`; nothing else compares file extensions.

Each format's module is imported on first use, so one format's optional dependency (OpenImageIO
for SOG, zstandard for SPZ v4) never stops the others. Every reader and writer raises
`SplatFileError` (a ValueError) naming the file and the problem; every writer is atomic.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..gaussians import Gaussians
from ..formats_common.errors import SplatFileError

__all__ = ["SplatFormat", "FORMATS", "format_for", "read", "write", "import_patterns",
           "export_formats", "filter_glob", "file_extensions", "SplatFileError"]


def _module(name: str):
    return importlib.import_module(f"{__package__}.{name}")


# Readers return (Gaussians, antialiased); writers take (gaussians, path, antialiased).


def _read_plain(module: str) -> Callable[[Path], tuple[Gaussians, bool]]:
    return lambda path: (_module(module).load(path), False)


def _write_plain(module: str) -> Callable[[Gaussians, Path, bool], None]:
    return lambda gaussians, path, antialiased: _module(module).save(gaussians, path)


def _read_spz(path: Path) -> tuple[Gaussians, bool]:
    return _module("spz").load_with_flag(path)


def _write_spz(gaussians: Gaussians, path: Path, antialiased: bool) -> None:
    _module("spz").save(gaussians, path, antialiased=antialiased)


def _read_sog(path: Path) -> tuple[Gaussians, bool]:
    gaussians, info = _module("sog").load_with_info(path)
    return gaussians, info.antialiased


def _write_sog(gaussians: Gaussians, path: Path, antialiased: bool) -> None:
    _module("sog").save(gaussians, path, antialiased=antialiased)


@dataclass(frozen=True)
class SplatFormat:
    """One row of the table."""

    name: str  # what a user calls it
    endings: tuple[str, ...]  # lower-case file name endings ("meta.json" is a whole name)
    reader: Callable[[Path], tuple[Gaussians, bool]] | None
    writer: Callable[[Gaussians, Path, bool], None] | None
    max_sh_degree: int  # what it stores; its writer ignores higher bands (`write` warns)
    stores_antialiased: bool  # records the antialiased (Mip filter) render mode
    quantisation: str  # what a save then load changes (details in the module docstring)
    needs: tuple[str, ...] = ()  # Python modules it imports, beyond numpy
    whole_name: bool = False  # `endings` are complete file names, not suffixes
    # Default (forward, up) axes for import and export (`core.axes`): what stands the format's
    # usual captures upright in Blender. Readers all return the 3DGS .ply frame (SPZ and glTF
    # convert from their declared RUB frame), whose captures are y-down like COLMAP's.
    axes: tuple[str, str] = ("Z", "-Y")
    notes: str = field(default="", compare=False)

    @property
    def can_read(self) -> bool:
        return self.reader is not None

    @property
    def can_write(self) -> bool:
        return self.writer is not None

    def matches(self, name: str) -> bool:
        name = name.lower()
        return any(name == e if self.whole_name else name.endswith(e) for e in self.endings)


FORMATS: tuple[SplatFormat, ...] = (
    # Longer endings first: ".compressed.ply" before ".ply", "lod-meta.json" before "meta.json".
    SplatFormat("Compressed PLY (SuperSplat)", (".compressed.ply",), _read_plain("ply"),
                _write_plain("compressed_ply_write"), 3, False,
                "256-Gaussian chunks: position and log scale 11/10/11 bits, colour 8 bits within "
                "each chunk's range, opacity 8 bits, rotation 2+3x10 bits, SH 8 bits in [-4, 4]"),
    SplatFormat("3DGS PLY", (".ply",), _read_plain("ply"), _write_plain("ply"), 3, False,
                "none (float32); a compressed ply is recognised from its header when read",
                notes="the standard layout every 3DGS tool reads"),
    SplatFormat("antimatter15 .splat", (".splat",), _read_plain("splat"), _write_plain("splat"), 0, False,
                "position float32; scale float32; colour, opacity and rotation 8 bits; no SH"),
    SplatFormat("Niantic SPZ", (".spz",), _read_spz, _write_spz, 3, True,
                "position 24-bit fixed point, log scale 1/16, colour and opacity 8 bits, rotation "
                "smallest-three 3x10 bits, SH 5 bits (degree 1) / 4 bits", needs=("zstandard",)),
    SplatFormat("SOG bundle (PlayCanvas)", (".sog",), _read_sog, _write_sog, 3, True,
                "position 16 bits (log domain), rotation 3x8 bits, log scale and colour 256-entry "
                "codebooks, opacity 8 bits, SH k-means palette (<= 65536) of 8-bit codebook values",
                needs=("OpenImageIO",)),
    SplatFormat("Streamed SOG (LOD set)", ("lod-meta.json",), _read_plain("sog_lod"), None, 3, False,
                "as SOG; the finest level is read", needs=("OpenImageIO",), whole_name=True,
                notes="read only: level 0 (the finest) with all its chunks; sog_lod.load picks another"),
    SplatFormat("SOG folder (PlayCanvas)", ("meta.json",), _read_sog, _write_sog, 3, True,
                "as the SOG bundle", needs=("OpenImageIO",), whole_name=True,
                notes="meta.json and its WebP images in one folder"),
    SplatFormat("glTF binary (KHR_gaussian_splatting)", (".glb",), _read_plain("gltf"), _write_plain("gltf"),
                3, False, "none (float32; scale and opacity stored activated, in a y-up frame)"),
    SplatFormat("glTF (KHR_gaussian_splatting)", (".gltf",), _read_plain("gltf"), _write_plain("gltf"),
                3, False, "as .glb; the buffer is embedded (base64)"),
)


def format_for(path: str | os.PathLike) -> SplatFormat:
    """The format of `path` (a folder holding lod-meta.json or meta.json counts as that file)."""
    path = Path(path)
    if path.is_dir():
        for name in ("lod-meta.json", "meta.json"):
            if (path / name).is_file():
                return format_for(path / name)
    for fmt in FORMATS:
        if fmt.matches(path.name):
            return fmt
    raise SplatFileError(path, f"unknown splat format {path.suffix or '(no extension)'!r}; "
                               f"expected one of {', '.join(import_patterns())}")


def _resolve(path: Path) -> Path:
    if path.is_dir():
        for name in ("lod-meta.json", "meta.json"):
            if (path / name).is_file():
                return path / name
    return path


def read(path: str | os.PathLike) -> tuple[Gaussians, bool]:
    """(Gaussians, antialiased) from any readable splat file; `antialiased` is False where the
    format does not record it."""
    path = Path(path)
    fmt = format_for(path)
    if not fmt.can_read:
        raise SplatFileError(path, f"{fmt.name} files cannot be read")
    try:
        return fmt.reader(_resolve(path))
    except MemoryError:  # each reader bounds what it allocates; this is the net under them
        raise SplatFileError(path, f"not enough memory to load this {fmt.name} file "
                                   f"(see formats_common.limits)") from None
    except RecursionError:
        raise SplatFileError(path, f"this {fmt.name} file nests too deeply to read") from None


def write(gaussians: Gaussians, path: str | os.PathLike, *, antialiased: bool = False) -> list[str]:
    """Write `gaussians` in the format `path` names; returns warnings (SH bands or the
    antialiased mode the format cannot hold)."""
    path = Path(path)
    fmt = format_for(path)
    if not fmt.can_write:
        raise SplatFileError(path, f"{fmt.name} files cannot be written")
    warnings = []
    if gaussians.degree > fmt.max_sh_degree:
        bands = f"{fmt.max_sh_degree + 1}-{gaussians.degree}"
        # The writer ignores them (after checking them, like everything it is given).
        warnings.append(f"{fmt.name} holds SH degree {fmt.max_sh_degree} at most: bands {bands} were dropped")
    if antialiased and not fmt.stores_antialiased:
        warnings.append(f"{fmt.name} does not record the antialiased render mode")
    fmt.writer(gaussians, path, antialiased)
    return warnings


def import_patterns() -> tuple[str, ...]:
    """Name endings the importers accept (".ply", "meta.json", ...), each once."""
    seen: dict[str, None] = {}
    for fmt in FORMATS:
        if fmt.can_read:
            seen.update(dict.fromkeys(fmt.endings))
    return tuple(seen)


def export_formats() -> tuple[SplatFormat, ...]:
    return tuple(f for f in FORMATS if f.can_write)


def file_extensions() -> str:
    """What Blender's FileHandler `bl_file_extensions` takes (".ply;.sog;.json;..."): the last
    suffix of every readable name ending; a dropped `.json` still goes through `format_for`."""
    suffixes: dict[str, None] = {}
    for fmt in FORMATS:
        if fmt.can_read:
            suffixes.update(dict.fromkeys(Path(e).suffix or e for e in fmt.endings))
    return ";".join(suffixes)


def filter_glob(formats: tuple[SplatFormat, ...] | None = None) -> str:
    """A Blender file-browser filter ("*.ply;*.sog;meta.json;...") for `formats` (all readable)."""
    formats = formats or tuple(f for f in FORMATS if f.can_read)
    globs: dict[str, None] = {}
    for fmt in formats:
        globs.update(dict.fromkeys(e if fmt.whole_name else f"*{e}" for e in fmt.endings))
    return ";".join(globs)
