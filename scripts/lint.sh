#!/usr/bin/env bash
# The lint checks CI runs (a few seconds): ruff over the Python (the rules in ruff.toml, which the
# code satisfies), and the C sources compiled with the build's warnings as errors for C11
# (-Wall -Wextra -Werror, as native/setup.py builds them) without producing anything.
set -euo pipefail
cd "$(dirname "$0")/.."

.venv/bin/ruff check .

python_include=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
for source in native/src/*.c; do
    "${CC:-cc}" -std=c11 -Wall -Wextra -Werror -fsyntax-only -Inative/include -I"$python_include" "$source"
done
echo "lint: ruff and the C sources are clean"
