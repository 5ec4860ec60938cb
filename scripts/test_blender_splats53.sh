#!/bin/bash
# Issue 24's checks in the official bpy 5.3.0 (Blender's own splat point clouds and the add-on),
# from the installed extension zip: tests/real_blender/splats53.py (about 2 minutes, 2 cores).
#   scripts/test_blender_splats53.sh [ZIP]     (default: dist/gaussian_splatting-*-linux_x64.zip)
# Needs ../shared/real-blender (bpy313.sh builds the bpy 5.3.0 venv once) and ../shared/data.
set -euo pipefail
HERE=$(cd "$(dirname "$0")/.." && pwd)
SHARED=${SHARED:-$HERE/../shared}
ZIP=${1:-$(ls "$HERE"/dist/gaussian_splatting-*-linux_x64.zip | head -1)}
"$SHARED/real-blender/bpy313.sh" 5.3.0 >/dev/null
IO="$("$SHARED/real-blender/root.sh" py313)/io/splats53"
rm -rf "$IO/work" && mkdir -p "$IO"
cp -r "$SHARED/data/splats" "$IO/" 2>/dev/null || true
cp "$HERE/tests/real_blender/splats53.py" "$HERE/tests/real_blender/deform53.py" \
    "$HERE/tests/real_blender/extension_kit.py" \
    "$HERE/tests/real_blender/scene_kit.py" "$IO/"
cp "$ZIP" "$IO/extension.zip"
exec "$SHARED/real-blender/bpy313.sh" 5.3.0 python /io/splats53/splats53.py \
    --zip /io/splats53/extension.zip --data /io/splats53/splats --work /io/splats53/work
