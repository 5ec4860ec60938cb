#!/usr/bin/env bash
# A splat object's display through import, Clean Up, Ctrl+Z, Ctrl+Shift+Z, an Edit Mode delete
# and Ctrl+Z, in a real Blender's UI under Xvfb (tests/real_blender/undo_display.py): after each
# step a screenshot must show the splats and no vertex dots (check.py undo). Needs root and the
# real-Blender roots (../shared/real-blender); the extension goes into a user configuration of
# its own under the io folder (the root's own configuration is left alone).
#
#   scripts/test_undo_display.sh SUITE EXTENSION.zip [IO_NAME]   (IO_NAME: under the root's io/,
#                                                                 default everyday-undo)
# Exit status 0 when every step passes; the figures are printed.
set -uo pipefail
cd "$(dirname "$0")/.."
SUITE=${1:?suite}; ZIP=${2:?extension zip}; NAME=${3:-everyday-undo}
RB=${REAL_BLENDER_SCRIPTS:-$(cd ../shared/real-blender 2>/dev/null && pwd)}
PY=.venv/bin/python
root=$("$RB/root.sh" "$SUITE")
io=$root/io/$NAME; t=/io/$NAME
rm -rf "$io" && mkdir -p "$io/out" "$io/user"
cp "$ZIP" "$io/extension.zip"
cp tests/real_blender/undo_display.py tests/real_blender/ui_kit.py "$io/"
$PY tests/real_blender/check.py undo-splats "$io/undo_splats.ply" || exit 1
blender() { "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user blender "$@"; }
blender --command extension install-file -r user_default -e $t/extension.zip > "$io/install.log" 2>&1 \
    || { echo "test_undo_display: install failed (see $io/install.log)"; exit 1; }
blender -b --python-expr "import bpy; bpy.ops.wm.read_homefile(use_empty=True); \
bpy.ops.wm.save_as_mainfile(filepath='$t/empty.blend')" > "$io/empty.log" 2>&1
[ -f "$io/empty.blend" ] || { echo "test_undo_display: no empty.blend (see $io/empty.log)"; exit 1; }
timeout 600 "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user sh -c \
    "xvfb-run -a -s '-screen 0 1600x900x24' blender --enable-event-simulate $t/empty.blend \
     --python $t/undo_display.py -- $t/undo_splats.ply $t/out > $t/ui.log 2>&1"
[ -f "$io/out/steps.json" ] || { echo "test_undo_display: no steps.json (see $io/ui.log)"; exit 1; }
$PY tests/real_blender/check.py undo "$io/out"
