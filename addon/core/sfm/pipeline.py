"""Photos or a video to a COLMAP workspace, in stages that are cached and resumed.

    steps = reconstruct("~/Phone/vase", "~/vase_scene", Options(threads=2))
    for step in steps:                     # a generator: stop iterating to cancel
        print(step.line())                 # "finding features 12/40 photos, 0:21 left"
    report = steps.value                   # (see `run`)

The workspace FOLDER gets `images/` (the photos, upright and bounded, or the video's chosen
frames), `database.db` (COLMAP's features and matches), `sparse/0/` (the kept model) and
`reconstruction.json` (what was done, with which inputs and options). Each stage records a key
of its inputs when it completes: running again skips every stage whose key still matches and
resumes an interrupted one (COLMAP skips the photos and pairs the database already holds), so a
cancelled or crashed run costs only the batch it was in. Every file is written atomically, and
`sparse/0` is replaced in one rename, so a stopped run never leaves half a model for Import
COLMAP to read.

A folder that is not empty and holds no `reconstruction.json` is refused: the workspace is
the add-on's to delete from, and a user's own folder must never be.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Generator

from ..atomic import atomic_write
from ..colmap.errors import import_pycolmap
from . import mapping, pairs
from .errors import ReconstructionError
from .photos import DEFAULT_MAX_SIZE, Photo, UnreadablePhoto, output_name, write_photo
from .source import Source, find_source
from .video import DEFAULT_FRAME_COUNT, sample_video

STATE_FILE = "reconstruction.json"
STATE_VERSION = 1
SIFT_MAX_SIZE = 1600  # SIFT on at most this many pixels on the long side
# "accurate": SIFT with affine shapes and domain-size pooling (DSP-SIFT): on the demo the
# cameras' largest rotation error halves (0.32 -> 0.16 deg) and the held-out PSNR they cost
# a model trained on the exact cameras drops from 0.67 to 0.20 dB, for 3.6x the extraction
# time (docs/benchmarks/reconstruction.md). "fast": COLMAP's plain SIFT.
FEATURES = ("accurate", "fast")
# "auto": a camera per photo for a folder of photos, one shared by a video's frames. On cup's 77
# phone photos a camera each trained to 31.53 dB held-out against 30.71 with one shared camera
# (and 31.13 on cup's own model, a camera per photo): a phone's focal length moves with its
# focus. The demo's renders (one true camera) place within 0.18 deg either way.
CAMERAS = ("auto", "shared", "per-photo")
EXTRACT_BATCH = 8  # photos per extraction call: the unit of progress and of cancelling
MATCH_BATCH = 200  # pairs per matching call
STAGES = ("photos", "features", "matching", "mapping")
# Shares of the progress bar (typical shares of the time, docs/benchmarks/reconstruction.md).
WEIGHTS = {"photos": 0.1, "features": 0.35, "matching": 0.35, "mapping": 0.2}
TITLES = {"photos": "reading photos", "features": "finding features", "matching": "matching",
          "mapping": "mapping"}


@dataclass
class Options:
    frames: int = DEFAULT_FRAME_COUNT  # frames to take from a video
    max_size: int = DEFAULT_MAX_SIZE  # long side of the workspace's photos (0: as they are)
    features: str = "accurate"  # FEATURES
    cameras: str = "auto"  # CAMERAS
    matching: str = "auto"  # pairs.METHODS
    mapper: str = "incremental"  # mapping.MAPPERS (incremental: the reliable one, docs/benchmarks)
    threads: int = 0  # 0: every core

    def check(self) -> None:
        if self.cameras not in CAMERAS:
            raise ValueError(f"cameras {self.cameras!r}: expected one of {CAMERAS}")
        if self.features not in FEATURES:
            raise ValueError(f"features {self.features!r}: expected one of {FEATURES}")
        if self.matching not in pairs.METHODS:
            raise ValueError(f"matching {self.matching!r}: expected one of {pairs.METHODS}")
        if self.mapper not in mapping.MAPPERS:
            raise ValueError(f"mapper {self.mapper!r}: expected one of {mapping.MAPPERS}")
        if self.frames < 3:
            raise ValueError(f"frames {self.frames}: at least 3")
        if self.max_size < 0 or 0 < self.max_size < 64:
            raise ValueError(f"max size {self.max_size}: 0 (as they are) or at least 64")


@dataclass
class Step:
    """Where the work is: a stage, how much of it is done, and an estimate of what is left."""

    stage: str  # one of STAGES
    done: int
    total: int  # 0: unknown
    unit: str  # "photos", "frames", "pairs", "photos placed"
    eta: float | None = None  # seconds left in this stage

    @property
    def fraction(self) -> float:
        """Of the whole reconstruction."""
        before = sum(WEIGHTS[s] for s in STAGES[:STAGES.index(self.stage)])
        within = min(self.done / self.total, 1.0) if self.total else 0.0
        return before + WEIGHTS[self.stage] * within

    def line(self) -> str:
        count = f"{self.done:,}/{self.total:,}" if self.total else f"{self.done:,}"
        eta = "" if self.eta is None else f", {format_seconds(self.eta)} left"
        return f"{TITLES[self.stage]} {count} {self.unit}{eta}"

    def to_json(self) -> dict:
        return {**asdict(self), "fraction": self.fraction, "line": self.line()}


def format_seconds(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@dataclass
class Report:
    workspace: Path
    source: Path
    kind: str
    photos: int  # photos (or frames) given to COLMAP
    registered: list[str]
    left_out: list[tuple[str, str]]  # (name, why) of photos in no kept model
    skipped: list[tuple[str, str]]  # (source file, why) not used at all
    matching: str
    mapper: str
    cameras: int
    points: int
    used_priors: bool
    retried: bool
    seconds: dict[str, float] = field(default_factory=dict)  # per stage run (not cached)
    cached: list[str] = field(default_factory=list)  # stages taken from an earlier run

    def summary(self) -> str:
        lines = [f"registered {len(self.registered)} of {self.photos} "
                 f"{'frames' if self.kind == 'video' else 'photos'} ({self.cameras} camera(s), "
                 f"{self.points:,} points, {self.matching} matching, {self.mapper} mapping) "
                 f"in {self.workspace}"]
        if self.retried and not self.used_priors:
            lines.append("  the photos' EXIF focal lengths did not fit them (cropped or "
                         "exported?): the cameras were found without them")
        lines += [f"  left out {name}: {why}" for name, why in self.left_out]
        lines += [f"  skipped {name}: {why}" for name, why in self.skipped]
        return "\n".join(lines)

    def to_json(self) -> dict:
        data = asdict(self)
        data["workspace"], data["source"] = str(self.workspace), str(self.source)
        return data

    @classmethod
    def from_json(cls, data: dict) -> "Report":
        return cls(**{**data, "workspace": Path(data["workspace"]),
                      "source": Path(data["source"]),
                      "left_out": [tuple(x) for x in data["left_out"]],
                      "skipped": [tuple(x) for x in data["skipped"]]})


class _Clock:
    """ETA of a stage from its rate so far."""

    def __init__(self) -> None:
        self.started = time.perf_counter()

    def step(self, stage: str, done: int, total: int, unit: str) -> Step:
        elapsed = time.perf_counter() - self.started
        eta = elapsed * (total - done) / done if done and total and elapsed > 1.0 else None
        return Step(stage, done, total, unit, eta)


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _source_key(source: Source, options: Options) -> str:
    files = [source.path] if source.kind == "video" else source.photos
    stats = [(f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files]
    return _key(STATE_VERSION, str(source.path), source.kind, stats, options.max_size,
                options.frames if source.kind == "video" else None)


class Workspace:
    """The output folder and its state file."""

    def __init__(self, folder: Path, source: Source) -> None:
        self.folder = folder
        self.images = folder / "images"
        self.database = folder / "database.db"
        self.model = folder / "sparse" / "0"
        self.state_file = folder / STATE_FILE
        self._claim(source)
        self.state = self._read_state()

    def _claim(self, source: Source) -> None:
        folder = self.folder
        if folder == source.path or (source.kind == "photos" and source.path.is_relative_to(folder)):
            raise ReconstructionError(f"{folder}: the output folder cannot hold the photos' "
                                      f"folder; choose another")
        if folder.exists() and not folder.is_dir():
            raise ReconstructionError(f"{folder}: exists and is not a folder")
        if folder.is_dir() and any(folder.iterdir()) and not self.state_file.is_file():
            raise ReconstructionError(f"{folder}: the folder is not empty and holds no earlier "
                                      f"reconstruction; choose an empty or new folder")
        try:
            self.images.mkdir(parents=True, exist_ok=True)
            probe = folder / f".write-test-{os.getpid()}"
            probe.write_bytes(b"0")
            probe.unlink()
        except OSError as error:
            raise ReconstructionError(f"{folder}: cannot write there ({error.strerror or error})"
                                      ) from None

    def _read_state(self) -> dict:
        try:
            state = json.loads(self.state_file.read_text(encoding="utf-8"))
            if state.get("version") == STATE_VERSION:
                return state
        except (OSError, ValueError):
            pass
        return {"version": STATE_VERSION, "stages": {}}

    def done(self, stage: str, key: str) -> bool:
        return self.state["stages"].get(stage) == key

    def finish(self, stage: str, key: str, **data) -> None:
        stages = self.state["stages"]
        for later in STAGES[STAGES.index(stage) + 1:]:
            stages.pop(later, None)
        stages[stage] = key
        self.state.update(data)
        self.save()

    def forget_from(self, stage: str) -> None:
        """A stage is redone: it and every later one are no longer done."""
        stages = self.state["stages"]
        for name in STAGES[STAGES.index(stage):]:
            stages.pop(name, None)
        self.save()

    def save(self) -> None:
        try:
            with atomic_write(self.state_file) as f:
                f.write(json.dumps(self.state, indent=1).encode("utf-8"))
        except OSError as error:
            raise ReconstructionError(f"{self.state_file}: cannot write ({error.strerror or error})"
                                      ) from None


def reconstruct(source_path: str | os.PathLike, folder: str | os.PathLike,
                options: Options | None = None) -> Generator[Step, None, Report]:
    """The stages as a generator of `Step`s; its return value (StopIteration.value) is the
    `Report`. Raises ReconstructionError for input that cannot become a scene."""
    options = options or Options()
    options.check()
    pycolmap = import_pycolmap()
    pycolmap.logging.minloglevel = 2  # COLMAP's own log: errors only
    pycolmap.set_random_seed(0)
    source = find_source(source_path)
    workspace = Workspace(Path(folder).expanduser().resolve(), source)
    threads = options.threads if options.threads > 0 else -1
    seconds: dict[str, float] = {}
    cached: list[str] = []

    # -- photos --------------------------------------------------------------------------------
    key = _source_key(source, options)
    started = time.perf_counter()
    if workspace.done("photos", key):
        photos = [Photo(**p) for p in workspace.state["photos"]]
        cached.append("photos")
    else:
        workspace.forget_from("photos")
        _clear(workspace)
        photos = yield from _write_photos(source, workspace, options)
        if len(photos) < 2:
            raise ReconstructionError(
                f"{source.path}: {len(photos)} usable photo(s); a scene needs at least two "
                f"overlapping views, better dozens from all around the subject"
                + "".join(f"\n  skipped {n}: {w}" for n, w in source.skipped))
        workspace.finish("photos", key, photos=[p.to_json() for p in photos],
                         skipped=source.skipped, source=str(source.path), kind=source.kind)
        seconds["photos"] = time.perf_counter() - started
    source.skipped = [tuple(s) for s in workspace.state.get("skipped", source.skipped)]

    # -- features ------------------------------------------------------------------------------
    per_photo = options.cameras == "per-photo" or (options.cameras == "auto"
                                                   and source.kind == "photos")
    key = _key(key, SIFT_MAX_SIZE, options.features, per_photo)
    started = time.perf_counter()
    if workspace.done("features", key):
        cached.append("features")
    else:
        if workspace.state.get("features_with") != [options.features, per_photo]:
            workspace.database.unlink(missing_ok=True)  # other features or cameras: again
        workspace.state["features_with"] = [options.features, per_photo]
        yield from _extract(pycolmap, workspace, photos, threads, options.features, per_photo)
        workspace.finish("features", key)
        seconds["features"] = time.perf_counter() - started

    # -- matching ------------------------------------------------------------------------------
    method = pairs.choose(options.matching, source.kind, len(photos))
    key = _key(key, method)
    started = time.perf_counter()
    if workspace.done("matching", key):
        cached.append("matching")
    else:
        if workspace.state.get("matched_with") != method:
            _clear_matches(pycolmap, workspace)
        workspace.state["matched_with"] = method
        yield from _match(pycolmap, workspace, photos, method, threads)
        workspace.finish("matching", key)
        seconds["matching"] = time.perf_counter() - started

    # -- mapping -------------------------------------------------------------------------------
    key = _key(key, options.mapper)
    started = time.perf_counter()
    if workspace.done("mapping", key) and (workspace.model / "images.bin").is_file():
        cached.append("mapping")
        result = workspace.state["result"]
    else:
        result = yield from _map(pycolmap, workspace, photos, options.mapper, threads)
        workspace.finish("mapping", key, result=result)
        seconds["mapping"] = time.perf_counter() - started

    return Report(workspace.folder, source.path, source.kind, len(photos),
                  result["registered"], [tuple(x) for x in result["left_out"]], source.skipped,
                  method, options.mapper, result["cameras"], result["points"],
                  result["used_priors"], result["retried"], seconds, cached)


def run(source_path, folder, options: Options | None = None, on_step=None) -> Report:
    """`reconstruct` to the end; `on_step(step)` sees every step."""
    steps = reconstruct(source_path, folder, options)
    while True:
        try:
            step = next(steps)
        except StopIteration as finished:
            return finished.value
        if on_step is not None:
            on_step(step)


def _clear(workspace: Workspace) -> None:
    """A new source or options: nothing made from the old ones may stay."""
    for path in (workspace.images, workspace.folder / "sparse", workspace.folder / "mapping"):
        shutil.rmtree(path, ignore_errors=True)
    workspace.database.unlink(missing_ok=True)
    workspace.images.mkdir(parents=True, exist_ok=True)


def _write_photos(source: Source, workspace: Workspace, options: Options):
    clock = _Clock()
    if source.kind == "video":
        steps = sample_video(source.path, workspace.images, options.frames, options.max_size)
        first_pass = True
        while True:
            try:
                done, total = next(steps)
            except StopIteration as finished:
                return finished.value
            if total and first_pass:
                first_pass, clock = False, _Clock()
            yield clock.step("photos", done, total, "frames written" if total else
                             "frames read")
    photos: list[Photo] = []
    taken: set[str] = set()
    for index, path in enumerate(source.photos):
        name = output_name(path, taken)
        try:
            photo = write_photo(path, workspace.images, name, options.max_size)
        except UnreadablePhoto as error:
            source.skipped.append((path.name, f"cannot be read ({_short(error, path)})"))
        else:
            photos.append(photo)
            taken.add(name)
        yield clock.step("photos", index + 1, len(source.photos), "photos")
    return photos


def _short(error: Exception, path: Path) -> str:
    return str(error).replace(f"{path}: ", "").strip() or type(error).__name__


def _extract(pycolmap, workspace: Workspace, photos: list[Photo], threads: int, features: str,
             per_photo: bool):
    """SIFT for every photo not yet in the database, in batches; a camera per photo
    (`per_photo`) or one per group of photos that share a size and lens (`Photo.camera_key`)."""
    db = pycolmap.Database.open(str(workspace.database))
    try:
        existing = {i.name: i.camera_id for i in db.read_all_images()
                    if db.exists_keypoints(i.image_id)}
    finally:
        db.close()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.max_image_size = SIFT_MAX_SIZE
    extraction.sift.estimate_affine_shape = extraction.sift.domain_size_pooling = \
        features == "accurate"
    groups: dict[tuple, list[Photo]] = {}
    for photo in photos:
        groups.setdefault(() if per_photo else photo.camera_key, []).append(photo)
    clock = _Clock()
    done = sum(p.name in existing for p in photos)
    for members in groups.values():
        camera = next((existing[p.name] for p in members if p.name in existing), None)
        todo = [p.name for p in members if p.name not in existing]
        for start in range(0, len(todo), EXTRACT_BATCH):
            batch = todo[start:start + EXTRACT_BATCH]
            reader = pycolmap.ImageReaderOptions()
            reader.camera_model = "SIMPLE_RADIAL"
            if camera is not None and not per_photo:
                reader.existing_camera_id = camera
            mode = pycolmap.CameraMode.PER_IMAGE if per_photo else pycolmap.CameraMode.SINGLE
            pycolmap.extract_features(str(workspace.database), str(workspace.images),
                                      image_names=batch, camera_mode=mode,
                                      reader_options=reader, extraction_options=extraction,
                                      device=pycolmap.Device.cpu)
            if camera is None and not per_photo:
                camera = _camera_of(pycolmap, workspace.database, batch[0])
            done += len(batch)
            yield clock.step("features", done, len(photos), "photos")


def _camera_of(pycolmap, database: Path, name: str) -> int | None:
    db = pycolmap.Database.open(str(database))
    try:
        image = db.read_image_with_name(name)
        return None if image is None else image.camera_id
    finally:
        db.close()


def _clear_matches(pycolmap, workspace: Workspace) -> None:
    if workspace.database.is_file():
        db = pycolmap.Database.open(str(workspace.database))
        try:
            db.clear_matches()
            db.clear_two_view_geometries()
        finally:
            db.close()


def _descriptors(pycolmap, database: Path, names: list[str]) -> list:
    db = pycolmap.Database.open(str(database))
    try:
        ids = {i.name: i.image_id for i in db.read_all_images()}
        return [db.read_descriptors(ids[n]).data if n in ids else [] for n in names]
    finally:
        db.close()


def _match(pycolmap, workspace: Workspace, photos: list[Photo], method: str, threads: int):
    names = [p.name for p in photos]
    if method == "exhaustive":
        chosen = pairs.exhaustive(len(names))
    elif method == "sequential":
        chosen = pairs.sequential(len(names))
    else:
        similar = pairs.similarity(_descriptors(pycolmap, workspace.database, names))
        chosen = pairs.retrieval(similar)
    db = pycolmap.Database.open(str(workspace.database))
    try:
        ids = {i.name: i.image_id for i in db.read_all_images()}
        # Photos without features are not in the database: nothing to match them with.
        chosen = [(i, j) for i, j in chosen if names[i] in ids and names[j] in ids]
        todo = [(i, j) for i, j in chosen
                if not db.exists_two_view_geometry(ids[names[i]], ids[names[j]])]
    finally:
        db.close()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    list_file = workspace.folder / "pairs.txt"
    clock = _Clock()
    done = len(chosen) - len(todo)
    for start in range(0, len(todo), MATCH_BATCH):
        batch = todo[start:start + MATCH_BATCH]
        with atomic_write(list_file) as f:
            f.write("".join(f"{names[i]} {names[j]}\n" for i, j in batch).encode("utf-8"))
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(list_file)
        pycolmap.match_image_pairs(str(workspace.database), matching_options=matching,
                                   pairing_options=pairing, device=pycolmap.Device.cpu)
        done += len(batch)
        yield clock.step("matching", done, len(chosen), "pairs")
    list_file.unlink(missing_ok=True)


def _map(pycolmap, workspace: Workspace, photos: list[Photo], mapper: str, threads: int):
    scratch = workspace.folder / "mapping"
    shutil.rmtree(scratch, ignore_errors=True)
    clock = _Clock()
    steps = mapping.map_photos(pycolmap, mapper, workspace.database, workspace.images, scratch,
                               photos, threads)
    try:  # photos placed so far (the incremental mapper counts them; the global does not)
        while True:
            try:
                placed = next(steps)
            except StopIteration as finished:
                mapped = finished.value
                break
            yield clock.step("mapping", min(placed, len(photos)), len(photos), "photos placed")
    finally:
        steps.close()  # cancelled: the mapper stops and is waited for
    if mapped.model is None or len(mapped.registered) < 2:
        shutil.rmtree(scratch, ignore_errors=True)
        raise ReconstructionError(
            f"{workspace.folder}: no cameras could be placed: the {len(photos)} photos do not "
            f"overlap enough (each part of the subject should be in several photos taken from "
            f"a little apart), or they are too blurred or too plain")
    reasons = mapping.left_out(pycolmap, workspace.database, photos, mapped)
    _write_model(mapped.model, workspace)
    shutil.rmtree(scratch, ignore_errors=True)
    yield Step("mapping", len(mapped.registered), len(photos), "photos placed")
    return {"registered": sorted(mapped.registered), "left_out": reasons,
            "cameras": mapped.model.num_cameras(), "points": mapped.model.num_points3D(),
            "used_priors": mapped.used_priors, "retried": mapped.retried}


def _write_model(model, workspace: Workspace) -> None:
    """sparse/0 replaced in one rename (the old one removed after)."""
    sparse = workspace.model.parent
    sparse.mkdir(parents=True, exist_ok=True)
    fresh = sparse / f".0.{os.getpid()}.tmp"
    shutil.rmtree(fresh, ignore_errors=True)
    fresh.mkdir()
    model.write(str(fresh))
    old = sparse / f".0.{os.getpid()}.old"
    if workspace.model.exists():
        os.replace(workspace.model, old)
    os.replace(fresh, workspace.model)
    shutil.rmtree(old, ignore_errors=True)
