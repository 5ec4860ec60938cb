#!/usr/bin/env bash
# The native module under sanitizers (Linux, gcc or clang):
#   1. splatcore built with AddressSanitizer + UndefinedBehaviorSanitizer (any report aborts),
#      running the native tests (forward, backward, training kernels, bad input, hard cases,
#      threads, deformation) and the fuzz test;
#   2. splatcore built with ThreadSanitizer, running the threaded tests (the thread pool, renders
#      from several Python threads, thread counts, the deformation pass on 1, 2 and 5 threads).
# The sanitized builds go to build/sanitize/ and are put first on PYTHONPATH; .venv's own
# splatcore is untouched. Python itself is not instrumented, so the sanitizer runtime is
# preloaded (with libstdc++, so that pycolmap's C++ exceptions still work); leak checking is off
# (the interpreter keeps its memory until exit) and a failed allocation returns NULL (the fuzz
# test's memory limit must give Python's MemoryError, not an abort).
#
#   ./scripts/sanitize.sh            # both runs
#   ./scripts/sanitize.sh asan       # or only one of them: asan | tsan
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
CC=${CC:-gcc}
which=${1:-all}
[ -x "$PY" ] || ./scripts/bootstrap.sh

build() {  # build <name> <sanitizer flags>
    local out="build/sanitize/$1"
    rm -rf "$out" && mkdir -p "$out/tmp"
    (cd native && CC="$CC" CFLAGS="$2 -fno-omit-frame-pointer -g" LDFLAGS="$2" \
        "../$PY" setup.py -q build_ext --build-lib "../$out" --build-temp "../$out/tmp" >/dev/null)
    rm -rf native/build native/*.egg-info "$out/tmp"
}

run() {  # run <name> <sanitizer runtime> <pytest arguments...>: the tests on build <name>
    local name=$1 runtime=$2
    shift 2
    local out="$PWD/build/sanitize/$name"
    local options="halt_on_error=1:log_path=$out/report"
    (
        export PYTHONPATH="$out"
        export OPENBLAS_NUM_THREADS=1  # numpy's BLAS threads are not instrumented: false races
        export LD_PRELOAD="$($CC -print-file-name="$runtime") $($CC -print-file-name=libstdc++.so.6)"
        export ASAN_OPTIONS="$options:detect_leaks=0:abort_on_error=1:allocator_may_return_null=1"
        export UBSAN_OPTIONS="$options:print_stacktrace=1"
        export TSAN_OPTIONS="$options:second_deadlock_stack=1:report_signal_unsafe=0"
        "$PY" -c "import splatcore; assert splatcore.__file__.startswith('$out'), splatcore.__file__" &&
            "$PY" -m pytest -q -p no:cacheprovider "$@"
    ) || { cat "$out"/report.* 2>/dev/null; exit 1; }
}

NATIVE_TESTS=(tests/core/render/test_render_reference.py tests/core/train/test_backward.py tests/core/train/test_train_kernels.py
              tests/core/render/test_bad_arguments.py tests/core/render/test_hard_cases.py tests/core/render/test_threads.py
              tests/core/deform)

if [ "$which" = all ] || [ "$which" = asan ]; then
    echo "sanitize: AddressSanitizer + UndefinedBehaviorSanitizer"
    build asan "-fsanitize=address,undefined -fno-sanitize-recover=all"
    run asan libasan.so "${NATIVE_TESTS[@]}" tests/core/formats/test_fuzz.py
fi
if [ "$which" = all ] || [ "$which" = tsan ]; then
    echo "sanitize: ThreadSanitizer"
    build tsan "-fsanitize=thread"
    run tsan libtsan.so tests/core/render/test_threads.py tests/core/train/test_train_kernels.py \
        tests/core/deform/test_apply.py
fi
echo "sanitize: clean"
