#!/usr/bin/env bash
# The main thread's stalls after one new object appears, in a real Blender under Xvfb
# (tests/real_blender/ui_new_object.py): Add Cube against a splat object as training makes it,
# with the scene's F12 bridge (and its helper scene) set up before it, with it, or after it
# (issue 36). Run it beside other work too (e.g. `python3 -c 'while 1: pass' &`). A benchmark
# that prints a table, never a test. Needs the real-Blender roots (../shared/real-blender); builds the linux-x64 zip.
#
#   benchmarks/bench_ui_new_object_blender.sh [SUITE] [ROUNDS]     (SUITE: trixie = Blender 4.3, sid = 5.2)
set -uo pipefail
cd "$(dirname "$0")/.."
SUITE=${1:-trixie}; ROUNDS=${2:-3}
. benchmarks/real_blender_ui.sh "$SUITE" splat-ui-new-object
cp -r examples/demo_colmap "$io/colmap"
cp examples/demo_scene.ply "$io/splats.ply"
blender -b --python-expr "import bpy; bpy.ops.wm.read_homefile(); \
bpy.ops.wm.save_as_mainfile(filepath='$t/start.blend')" > "$io/start.log" 2>&1
timeout $((40 * ROUNDS + 300)) "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user sh -c \
    "xvfb-run -a -s '-screen 0 1600x900x24' blender $t/start.blend \
     --python $t/ui_new_object.py -- $t/colmap $t/splats.ply $t/new_object.json $ROUNDS > $t/ui.log 2>&1"
[ -f "$io/new_object.json" ] || { echo "bench_ui_new_object_blender: no result (see $io/ui.log)"; exit 1; }
$PY - "$io/new_object.json" "$SUITE" <<'PYEOF'
import json, sys
r = json.load(open(sys.argv[1]))
if r["errors"]:
    sys.exit("bench_ui_new_object_blender: " + r["errors"][0])
print(f"Blender {'.'.join(map(str, r['version']))} ({sys.argv[2]}) under Xvfb: the main thread's stalls"
      f" over 50 ms in the 4 s after one new object appears")
print("| object | trials | stalls per trial | longest per trial, ms | first three stalls of the first trial, ms |")
print("| --- | ---: | ---: | --- | --- |")
for kind, label in r["kinds"].items():
    trials = r["trials"][kind]
    longest = [max(t, default=0) for t in trials]
    counts = sorted(len(t) for t in trials)
    print(f"| {label} | {len(trials)} | {counts[0]}-{counts[-1]} | {', '.join(map(str, longest))} | "
          f"{', '.join(map(str, trials[0][:3])) if trials else ''} |")
PYEOF
