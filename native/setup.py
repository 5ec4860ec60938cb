"""Builds `splatcore` as one abi3 extension (Python limited API 3.11) from the C11 sources."""

import sys
from pathlib import Path

from setuptools import Extension, setup

HERE = Path(__file__).parent
SOURCES = sorted(str(p.relative_to(HERE)) for p in (HERE / "src").glob("*.c"))
HEADERS = sorted(str(p.relative_to(HERE)) for p in [*(HERE / "include").glob("*.h"),
                                                     *(HERE / "src").glob("*.h")])

if sys.platform == "win32":
    FLAGS = ["/O2", "/W4", "/WX", "/std:c11", "/experimental:c11atomics"]
else:
    # -fno-trapping-math lets branch-free selects vectorise; -ffp-contract=fast allows FMA.
    FLAGS = ["-std=c11", "-O3", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden",
             "-ffp-contract=fast", "-fno-math-errno", "-fno-trapping-math"]

setup(
    ext_modules=[
        Extension(
            "splatcore",
            sources=SOURCES,
            depends=HEADERS,
            include_dirs=["include"],
            extra_compile_args=FLAGS,
            libraries=[] if sys.platform == "win32" else ["m", "pthread"],
            py_limited_api=True,
        )
    ],
    options={"bdist_wheel": {"py_limited_api": "cp311"}},
)
