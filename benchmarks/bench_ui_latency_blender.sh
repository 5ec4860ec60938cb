#!/usr/bin/env bash
# How late a 10 ms timer on Blender's main thread runs while Train Gaussians runs from the UI, in
# a real Blender under Xvfb (tests/real_blender/ui_latency.py): the demo scene at 480x360, the
# defaults, SECONDS idle then SECONDS training. A benchmark that prints a table, never a test.
# Needs the real-Blender roots (../shared/real-blender) and builds the linux-x64 zip.
#
#   benchmarks/bench_ui_latency_blender.sh [SUITE] [SECONDS]     (SUITE: trixie = Blender 4.3, sid = 5.2)
set -uo pipefail
cd "$(dirname "$0")/.."
SUITE=${1:-trixie}; SECONDS_EACH=${2:-30}
. benchmarks/real_blender_ui.sh "$SUITE" splat-ui-latency
cp -r examples/demo_colmap "$io/colmap"
blender -b --python-expr "import bpy; bpy.ops.wm.read_homefile(); \
bpy.ops.wm.save_as_mainfile(filepath='$t/start.blend')" > "$io/start.log" 2>&1
timeout $((6 * SECONDS_EACH + 300)) "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user sh -c \
    "xvfb-run -a -s '-screen 0 1600x900x24' blender $t/start.blend \
     --python $t/ui_latency.py -- $t/colmap $t/latency.json $SECONDS_EACH > $t/ui.log 2>&1"
[ -f "$io/latency.json" ] || { echo "bench_ui_latency_blender: no result (see $io/ui.log)"; exit 1; }
$PY - "$io/latency.json" "$SUITE" <<'PYEOF'
import json, sys
import numpy as np
r = json.load(open(sys.argv[1]))
if r["errors"]:
    sys.exit("bench_ui_latency_blender: " + r["errors"][0])
print(f"Blender {'.'.join(map(str, r['version']))} ({sys.argv[2]}) under Xvfb, a {r['period_ms']:.0f} ms timer"
      f" on the main thread")
print("A stall: the main thread away longer than 50 ms (two ticks that far apart); by time, not")
print("by ticks (a percentile over the ticks that fired cannot see the time none did).")
print("| phase | ticks | in stalls > 50 ms (% of the time) | longest stall ms | median ms late | p95 | 3D view draws | training steps |")
print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
for name, p in r["phases"].items():
    late = np.array(p["late_ms"])
    gaps = late + r["period_ms"]                  # ms between consecutive ticks
    stalled = gaps[gaps > 50].sum() / gaps.sum()
    steps = p.get("steps", "")
    print(f"| {name} | {len(late)} | {100 * stalled:.1f} | {gaps.max():.0f} | {np.median(late):.1f} | "
          f"{np.percentile(late, 95):.1f} | {p['draws']} | {steps if steps is not None else p.get('note')} |")
PYEOF
