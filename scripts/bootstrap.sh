#!/usr/bin/env bash
# Sets up .venv in the repository root: Python 3.11, the pinned requirements, and the native
# module `splatcore` built from native/. Each step is skipped when its inputs have not changed,
# so running it again is quick.
set -euo pipefail
cd "$(dirname "$0")/.."

python=${PYTHON:-python3.11}
command -v "$python" >/dev/null 2>&1 || python=python3
if ! "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
    echo "bootstrap: Python 3.11 is needed (bpy 5.0.1 is built for it); set PYTHON=/path/to/python3.11" >&2
    exit 1
fi

stamp() { cat "$@" | sha256sum | cut -d' ' -f1; }

if [ ! -x .venv/bin/python ]; then
    echo "bootstrap: creating .venv"
    "$python" -m venv .venv
fi

wanted=$(stamp requirements.txt)
if [ "$(cat .venv/.requirements-stamp 2>/dev/null)" != "$wanted" ]; then
    echo "bootstrap: installing requirements"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -r requirements.txt
    echo "$wanted" > .venv/.requirements-stamp
fi

wanted=$(stamp native/setup.py native/pyproject.toml native/include/*.h native/src/*.h native/src/*.c)
if [ "$(cat .venv/.native-stamp 2>/dev/null)" != "$wanted" ] || ! .venv/bin/python -c 'import splatcore' 2>/dev/null; then
    echo "bootstrap: building the native module"
    rm -rf native/build
    .venv/bin/python -m pip install -q --no-build-isolation --force-reinstall --no-deps ./native
    rm -rf native/build native/*.egg-info
    echo "$wanted" > .venv/.native-stamp
fi

# `python -m addon ...` from any folder: the repository on the venv's path (a .pth file). Not
# for a .venv that is a link to another checkout's (that checkout's path is the one it holds).
if [ ! -L .venv ]; then
    site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
    pwd > "$site/gaussian_splatting_checkout.pth"
fi
