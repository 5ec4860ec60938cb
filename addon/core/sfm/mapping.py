"""Cameras and poses from the matches: COLMAP's incremental or global mapping, the largest model
kept, and why each photo left out was left out.

Focal length: each camera starts from its photos' EXIF prior (`photos.exif_focal_px`) when they
have one, else from COLMAP's guess (1.2 x the long side, no prior). A prior is never trusted
blindly: photos cropped or exported after capture keep an EXIF focal length that is off by
several times. A run with the priors is a poor start when fewer than `GOOD_SHARE` of the photos
register, or when a placed photo's focal length is off by more than `FOCAL_SPREAD` times from
the median of the photos it shares a size and a prior with (with a camera per photo, the demo's
photos under a prior five times too long placed all 30, one of them at 111 px against 400:
such a photo, however placed, is wrong). Then the mapping runs again without the priors, and
the run with more photos placed with a sane focal length is kept.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Generator

from .photos import Photo

MAPPERS = ("incremental", "global")
DEFAULT_FOCAL_FACTOR = 1.2  # COLMAP's focal length guess: 1.2 x the long side
GOOD_SHARE = 0.8
FOCAL_SPREAD = 1.5  # photos of one size and one EXIF prior: focal lengths within this factor
MIN_MATCHES = 15  # inlier matches that make a verified pair (COLMAP's min_num_matches)


@dataclass
class Mapped:
    """The outcome of mapping: the kept model (None: nothing registered) and the others."""

    model: object | None  # pycolmap.Reconstruction
    others: list = field(default_factory=list)
    used_priors: bool = False
    retried: bool = False

    @property
    def registered(self) -> set[str]:
        if self.model is None:
            return set()
        return {image.name for image in self.model.images.values() if image.has_pose}

    def focal_outliers(self, photos: list[Photo]) -> set[str]:
        """Placed photos whose camera's focal length is more than FOCAL_SPREAD times off the
        median of the placed photos of the same size and EXIF prior (`Photo.camera_key`)."""
        if self.model is None:
            return set()
        keys = {p.name: p.camera_key for p in photos}
        groups: dict[tuple, list[tuple[str, float]]] = {}
        for image in self.model.images.values():
            if image.has_pose and image.name in keys:
                focal = float(self.model.cameras[image.camera_id].mean_focal_length())
                groups.setdefault(keys[image.name], []).append((image.name, focal))
        outliers = set()
        for members in groups.values():
            median = sorted(f for _, f in members)[len(members) // 2]
            outliers |= {name for name, f in members
                         if not median / FOCAL_SPREAD <= f <= median * FOCAL_SPREAD}
        return outliers

    def score(self, photos: list[Photo]) -> tuple[int, int]:
        """What decides between two runs: the photos placed with a sane focal length, then the
        fewer placed with an absurd one."""
        outliers = len(self.focal_outliers(photos))
        return len(self.registered) - outliers, -outliers


def set_cameras(pycolmap, database: Path, photos: list[Photo], use_priors: bool) -> None:
    """Start every camera from its photos' EXIF focal length (`use_priors`) or COLMAP's guess."""
    by_name = {p.name: p for p in photos}
    db = pycolmap.Database.open(str(database))
    try:
        photo_of_camera: dict[int, Photo] = {}
        for image in db.read_all_images():
            if image.name in by_name:
                photo_of_camera.setdefault(image.camera_id, by_name[image.name])
        for camera in db.read_all_cameras():
            photo = photo_of_camera.get(camera.camera_id)
            if photo is None:
                continue
            prior = photo.focal_px if use_priors else None
            focal = prior or DEFAULT_FOCAL_FACTOR * max(camera.width, camera.height)
            params = list(camera.params)
            params[0] = focal
            camera.params = params
            camera.has_prior_focal_length = prior is not None
            db.update_camera(camera)
    finally:
        db.close()


def run_mapper(pycolmap, mapper: str, database: Path, images_dir: Path, output: Path,
               threads: int, on_image: Callable[[], None] | None = None,
               cancel=None) -> list:
    """The reconstructions COLMAP finds (largest first). `cancel`: a pycolmap
    CancellationToken (the incremental mapper stops at its next photo; the global one has none)."""
    output.mkdir(parents=True, exist_ok=True)
    if mapper == "global":
        options = pycolmap.GlobalPipelineOptions()
        options.num_threads = threads
        options.random_seed = 0
        found = pycolmap.global_mapping(str(database), str(images_dir), str(output), options)
    else:
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = threads
        options.random_seed = 0
        options.min_model_size = 3
        found = pycolmap.incremental_mapping(str(database), str(images_dir), str(output),
                                             options, next_image_callback=on_image,
                                             cancellation_token=cancel)
    models = list(found.values())
    models.sort(key=lambda m: -m.num_reg_images())
    return models


def map_photos(pycolmap, mapper: str, database: Path, images_dir: Path, scratch: Path,
               photos: list[Photo], threads: int) -> Generator[int, None, Mapped]:
    """Map with the EXIF priors where there are any, again without them after a poor start (too
    few photos placed, or some placed with an absurd focal length); the run that places more
    with a sane focal length wins. A generator: COLMAP maps on a worker thread
    (it releases Python's lock) while this yields the photos placed so far, about 5 times a
    second; closing it cancels the mapper and waits for it."""
    attempts = [True, False] if any(p.focal_px for p in photos) else [False]
    best: Mapped | None = None
    for number, use_priors in enumerate(attempts):
        set_cameras(pycolmap, database, photos, use_priors)
        models = yield from _on_a_thread(pycolmap, mapper, database, images_dir,
                                         scratch / str(number), threads)
        mapped = Mapped(models[0] if models else None, models[1:], use_priors, number > 0)
        if best is None or mapped.score(photos) > best.score(photos):
            best = mapped
        if len(best.registered) >= GOOD_SHARE * len(photos) and not best.focal_outliers(photos):
            break
    return best


def _on_a_thread(pycolmap, mapper, database, images_dir, output, threads):
    placed = [0]
    outcome: dict = {}
    cancel = pycolmap.CancellationToken()

    def work() -> None:
        try:
            outcome["models"] = run_mapper(pycolmap, mapper, database, images_dir, output,
                                           threads, lambda: placed.__setitem__(0, placed[0] + 1),
                                           cancel)
        except BaseException as error:  # handed to the caller below
            outcome["error"] = error

    worker = threading.Thread(target=work, name="colmap-mapping", daemon=True)
    worker.start()
    try:
        while worker.is_alive():
            worker.join(0.2)
            yield placed[0]
    finally:
        if worker.is_alive():
            cancel.cancel()
            worker.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["models"]


def left_out(pycolmap, database: Path, photos: list[Photo], mapped: Mapped
             ) -> list[tuple[str, str]]:
    """(photo name, why) for every photo the kept model does not hold."""
    registered = mapped.registered
    elsewhere: dict[str, int] = {}  # name -> the size of the largest other model holding it
    for model in mapped.others:  # largest first
        size = model.num_reg_images()
        for image in model.images.values():
            if image.has_pose:
                elsewhere.setdefault(image.name, size)
    db = pycolmap.Database.open(str(database))
    try:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        features = {name: db.num_keypoints_for_image(i) for name, i in ids.items()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
    finally:
        db.close()
    verified: set[int] = set()
    for pair_id, count in zip(pair_ids, inliers):
        if count >= MIN_MATCHES:
            verified.update(pycolmap.pair_id_to_image_pair(pair_id))
    reasons = []
    for photo in photos:
        if photo.name in registered:
            continue
        image_id = ids.get(photo.name)
        if image_id is None or not features.get(photo.name):
            why = "no features found (a blank, dark or blurred photo?)"
        elif image_id not in verified:
            why = "overlaps no other photo (no matches that agree on a camera motion)"
        elif photo.name in elsewhere:
            why = (f"belongs to a separate model of {elsewhere[photo.name]} photos (another "
                   f"capture, or a part that does not connect to the rest)")
        else:
            why = "too few matches to place it in the model"
        reasons.append((photo.name, why))
    return reasons
