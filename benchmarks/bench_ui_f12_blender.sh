#!/usr/bin/env bash
# F12 in a real Blender's UI (under Xvfb), the two ways the splat composite can read the meshes'
# render: through Blender's render cache (the add-on as it is) and by saving the Render Result
# from the render thread (before 2026-11-29; it can hang Blender); and, for scale, the same
# scene's F12 without splats (the objects and the bridge removed), with and without Blender's
# render cache. The scene of scripts/test_real_blender.sh (Workbench meshes, 400 splats) at
# WxH; RUNS F12s per way, the ways alternated twice; with the longest the main thread (a 20 ms
# timer) was away.
# A benchmark that prints a table, never a test.
#
#   benchmarks/bench_ui_f12_blender.sh [SUITE] [WxH] [RUNS]    (SUITE: trixie = Blender 4.3, sid = 5.2)
set -uo pipefail
cd "$(dirname "$0")/.."
SUITE=${1:-sid}; SIZE=${2:-1920x1080}; RUNS=${3:-5}
. benchmarks/real_blender_ui.sh "$SUITE" splat-ui-f12
$PY tests/real_blender/check.py make "$io/splats.npz"
blender -b --factory-startup --python $t/scene.py -- $t/splats.npz $t/scene.blend > "$io/scene.log" 2>&1
[ -f "$io/scene.blend" ] || { echo "bench_ui_f12_blender: no scene (see $io/scene.log)"; exit 1; }
for turn in 1 2; do
    for mode in cache save_render meshes_only meshes_only_cache; do
        timeout 600 "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user sh -c \
            "xvfb-run -a -s '-screen 0 1600x900x24' blender $t/scene.blend \
             --python $t/ui_f12_timing.py -- $t/$mode-$turn.json $SIZE $RUNS $mode > $t/$mode-$turn.log 2>&1"
        [ -f "$io/$mode-$turn.json" ] || { echo "bench_ui_f12_blender: no result (see $io/$mode-$turn.log)"; exit 1; }
    done
done
$PY - "$io" "$SUITE" <<'PYEOF'
import glob, json, os, sys
import numpy as np
results = [json.load(open(p)) for p in sorted(glob.glob(os.path.join(sys.argv[1], "*-[12].json")))]
first = results[0]
print(f"Blender {'.'.join(map(str, first['version']))} ({sys.argv[2]}) under Xvfb, F12 at {first['size']}, "
      f"{sum(len(r['runs']) for r in results) // 4} per way; medians (min-max) in ms")
print("| the meshes' render read | F12, wall | the meshes' render until the compositor | the add-on's composite | the UI's longest stall | saved from the Render Result |")
print("| --- | ---: | ---: | ---: | ---: | ---: |")
for mode, label in (("cache", "from the render cache (now)"),
                    ("save_render", "saved by the render thread (before)"),
                    ("meshes_only", "no splats (the meshes alone)"),
                    ("meshes_only_cache", "no splats, Cache Result on")):
    runs = [run for r in results if r["mode"] == mode for run in r["runs"]]
    def cell(key):
        v = np.array([run[key] for run in runs if run[key] is not None])
        return f"{np.median(v):.0f} ({v.min():.0f}-{v.max():.0f})" if len(v) else "-"
    print(f"| {label} | {cell('wall_ms')} | {cell('meshes_ms')} | {cell('addon_ms')} | {cell('longest_stall_ms')} | "
          f"{sum(run['saved'] for run in runs)} of {len(runs)} |")
PYEOF
