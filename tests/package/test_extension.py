"""The extension zip, installed the way a user (or a render-farm image) installs it, then used.

1. `scripts/build_extension.py` builds the linux-x64 zip (manifest at its root, the add-on
   package, the native wheel and the dependencies' wheels under wheels/).
2. A fresh Blender process (the bpy wheel) with its own user folder installs it with
   `bpy.ops.extensions.package_install_files(..., enable_on_install=True)`, builds a scene with
   the extension's operators (splats, a cube, a camera), saves it and the preferences.
3. Another fresh process, like a farm node running `blender -b scene.blend -a`, reads the
   preferences (which enables the extension, as Blender's startup does), opens the file and
   renders the animation; the frames must be the exact composite.
4. The headless example runs in that node too, through the installed extension, as
   `blender --background --python examples/render_headless.py` would.

In both processes `splatcore` may only be imported from the extension's own site-packages
(an import hook hides the development copy), so the test proves the zip's wheel is what runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import numpy as np

from addon.core import splat_io
from scenes import random_gaussians

ROOT = Path(__file__).resolve().parents[2]

PRELUDE = textwrap.dedent("""
    import importlib.abc, importlib.machinery, json, os, sys
    USER = os.environ["BLENDER_USER_RESOURCES"]

    class ExtensionOnly(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name != "splatcore":
                return None
            paths = [p for p in sys.path if p.startswith(USER)]
            spec = importlib.machinery.PathFinder.find_spec(name, paths)
            if spec is None:
                raise ModuleNotFoundError("splatcore only from the extension", name=name)
            return spec

    sys.meta_path.insert(0, ExtensionOnly())
    sys.path = [p for p in sys.path if os.path.abspath(p) != {root!r}]
    import bpy
""")

INSTALL = textwrap.dedent("""
    assert bpy.ops.extensions.package_install_files(
        filepath={zip!r}, repo="user_default", enable_on_install=True) == {{"FINISHED"}}
    import splatcore
    for obj in list(bpy.data.objects):   # (factory settings would also unload the extension)
        bpy.data.objects.remove(obj)
    scene = bpy.context.scene
    assert bpy.ops.splat.import_splats(filepath={splats!r}) == {{"FINISHED"}}
    bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.35, -2.5, 0.15))
    cube = bpy.context.active_object
    scene.frame_start, scene.frame_end = 1, 2
    for frame, x in ((1, -0.6), (2, 0.6)):
        cube.location.x = x
        cube.keyframe_insert("location", frame=frame)
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0, -6, 0), (1.5707963, 0, 0)
    scene.camera = camera
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.view_settings.view_transform = "Standard"
    scene.render.dither_intensity = 0.0
    bpy.ops.wm.save_as_mainfile(filepath={blend!r})
    bpy.ops.wm.save_userpref()
    print(json.dumps(dict(splatcore=splatcore.__file__, addons=list(bpy.context.preferences.addons.keys()))))
""")

FARM = textwrap.dedent("""
    bpy.ops.wm.read_userpref()              # what Blender's startup does: enabled extensions load
    bpy.ops.wm.open_mainfile(filepath={blend!r})
    scene = bpy.context.scene
    scene.render.filepath = {out!r} + "/frame_"
    assert bpy.ops.render.render(animation=True) == {{"FINISHED"}}   # what `-a` runs
    settings = scene.render.image_settings
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    scene.render.filepath = {out!r} + "/layers_"
    assert bpy.ops.render.render(animation=True) == {{"FINISHED"}}
    import splatcore
    ext = sys.modules[bpy.types.SPLAT_OT_import_splats.__module__.split(".blender.")[0]]
    from importlib import import_module
    core = ext.__name__ + ".core"
    exr_layers, render_mod, colour = (import_module(core + m)
                                      for m in (".images.exr_layers", ".render.renderer", ".colour"))
    gather = import_module(ext.__name__ + ".blender.sources.gather")
    cameras = import_module(ext.__name__ + ".blender.camera_adapter")
    errors = []
    for frame in (1, 2):
        scene.frame_set(frame)
        channels = exr_layers.read_channels({out!r} + f"/layers_{{frame:04d}}.exr")
        mesh = exr_layers.find_pass(channels, "ViewLayer", "Combined", "RGBA")
        depth = exr_layers.find_pass(channels, "ViewLayer", "Depth", "Z")[..., 0]
        depsgraph = bpy.context.evaluated_depsgraph_get()
        camera = cameras.camera_of(scene.camera.evaluated_get(depsgraph), scene.render)
        result = render_mod.render(gather.gather(depsgraph).gaussians, camera,
                                   mesh_rgba=colour.display_from_linear(mesh), mesh_depth=depth)
        rgba = colour.linear_from_display(
            __import__("numpy").concatenate([result.rgb, result.alpha[..., None]], -1))
        import numpy as np, OpenImageIO as oiio
        expected = np.round(np.clip(colour.srgb_encode(rgba[..., :3]), 0, 1) * 255)
        written = oiio.ImageBuf({out!r} + f"/frame_{{frame:04d}}.png").get_pixels(oiio.UINT8)
        mesh_only = np.round(np.clip(colour.srgb_encode(mesh[..., :3]), 0, 1) * 255)
        errors.append(dict(error=float(np.abs(written[..., :3] - expected).max()),
                           splats_seen=float(np.abs(written[..., :3] - mesh_only).max())))
    print(json.dumps(dict(splatcore=splatcore.__file__, frames=errors)))
""")


def run(script: str, user: Path, *args: str) -> dict:
    env = dict(__import__("os").environ, BLENDER_USER_RESOURCES=str(user))
    done = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True,
                          timeout=300, env=env, cwd=user.parent)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads([line for line in done.stdout.splitlines() if line.startswith("{")][-1])


def test_install_the_zip_and_render_like_a_farm_node(rng, tmp_path):
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"), "--platform",
                    "linux-x64", "--python", "3.11", "--out", str(dist)], check=True,
                   capture_output=True, timeout=600)
    (zip_path,) = dist.glob("gaussian_splatting-*-linux_x64.zip")
    with zipfile.ZipFile(zip_path) as archive:
        listed = archive.namelist()
        names = set(listed)
        assert len(listed) == len(names), "a name twice in the zip"
        manifest = tomllib.loads(archive.read("blender_manifest.toml").decode())
    assert {"blender_manifest.toml", "__init__.py", "blender/render/hooks.py",
            "core/render/renderer.py"} <= names
    wheels = {n for n in names if n.startswith("wheels/") and n.endswith(".whl")}
    assert sorted(manifest["wheels"]) == sorted(f"./{n}" for n in wheels)
    assert manifest["platforms"] == ["linux-x64"]
    for module in ("splatcore", "pycolmap", "openimageio", "xatlas", "zstandard", "av"):
        assert any(n.startswith(f"wheels/{module}-") for n in wheels), (module, wheels)
    assert not any("__pycache__" in n for n in names)

    splats = tmp_path / "splats.ply"
    splat_io.save(random_gaussians(rng, 400, 1, radius=1.0, stray=0.0), splats)
    user, blend, out = tmp_path / "user", tmp_path / "scene.blend", tmp_path / "out"
    out.mkdir()
    prelude = PRELUDE.format(root=str(ROOT))
    installed = run(prelude + INSTALL.format(zip=str(zip_path), splats=str(splats),
                                             blend=str(blend)), user)
    assert installed["splatcore"].startswith(str(user))
    assert "bl_ext.user_default.gaussian_splatting" in installed["addons"]

    farm = run(prelude + FARM.format(blend=str(blend), out=str(out)), user)
    assert farm["splatcore"].startswith(str(user))
    for frame in farm["frames"]:
        assert frame["error"] <= 1.0, frame
        assert frame["splats_seen"] > 20, frame

    # The headless example, through the installed extension (as `blender --background
    # --python examples/render_headless.py` runs it where the extension is enabled).
    example = prelude + textwrap.dedent(f"""
        bpy.ops.wm.read_userpref()
        sys.argv = ["render_headless.py", "--", "--engine", "BLENDER_WORKBENCH", "--size",
                    "48x27", "--frames", "2", "--out", {str(out / 'example')!r},
                    "--splats", {str(splats)!r}]
        import runpy
        runpy.run_path({str(ROOT / 'examples' / 'render_headless.py')!r}, run_name="__main__")
        import splatcore
        print(json.dumps(dict(splatcore=splatcore.__file__)))
    """)
    assert run(example, user)["splatcore"].startswith(str(user))
    for name in ("headless_still.png", "headless_0001.png", "headless_0002.png"):
        assert (out / "example" / name).stat().st_size > 0


def test_headless_example_with_plain_python(tmp_path):
    """`python examples/render_headless.py` with the bpy wheel (the add-on from this repo)."""
    done = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "render_headless.py"), "--engine", "CYCLES",
         "--size", "64x36", "--samples", "1", "--frames", "3", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    import OpenImageIO as oiio

    frames = [np.asarray(oiio.ImageBuf(str(tmp_path / f"headless_{i:04d}.png")).get_pixels(
        oiio.UINT8), np.int32) for i in (1, 2)]
    still = np.asarray(oiio.ImageBuf(str(tmp_path / "headless_still.png")).get_pixels(oiio.UINT8))
    assert still.shape == (36, 64, 4) and np.abs(frames[0] - frames[1]).max() > 20
    assert "Gaussian splats: 18,000 splats" in done.stdout
