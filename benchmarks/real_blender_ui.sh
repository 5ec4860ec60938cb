# Sourced by the benchmarks that drive a real Blender's UI (bench_ui_*_blender.sh): builds the
# linux-x64 zip, prepares SUITE's root (../shared/real-blender) with a fresh folder /io/NAME
# holding the zip and tests/real_blender/*.py, and installs the extension into a user folder of
# its own. Then: $PY, $RB, $io (the folder here), $t (the same inside), and `blender ARGS`.
#
#   . benchmarks/real_blender_ui.sh SUITE NAME
SUITE=$1; NAME=$2
RB=${REAL_BLENDER_SCRIPTS:-$(cd ../shared/real-blender 2>/dev/null && pwd)}
[ -n "$RB" ] && [ -x "$RB/run.sh" ] || { echo "$NAME: no ../shared/real-blender" >&2; exit 1; }
PY=.venv/bin/python
$PY scripts/build_extension.py --platform linux-x64 > /dev/null || exit 1
zip=$(ls -t dist/gaussian_splatting-*-linux_x64.zip | head -1)
"$RB/setup.sh" "$SUITE" > /dev/null || exit 1
io=$("$RB/root.sh" "$SUITE")/io/$NAME; t=/io/$NAME
rm -rf "$io" && mkdir -p "$io/user"
cp "$zip" "$io/extension.zip"
cp tests/real_blender/*.py "$io/"
blender() { "$RB/run.sh" "$SUITE" env BLENDER_USER_RESOURCES=$t/user blender "$@"; }
blender --command extension install-file -r user_default -e $t/extension.zip > "$io/install.log" 2>&1 \
    || { echo "$NAME: install failed (see $io/install.log)"; exit 1; }
