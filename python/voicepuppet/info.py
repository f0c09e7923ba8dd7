"""``voicepuppet info``: versions, build type, compiler and SIMD of the compiled core."""

from __future__ import annotations

import platform


def collect() -> dict:
    """Versions of voicepuppet, its compiled core and its main dependencies, and the BLAS numpy
    uses with its current thread count, as a dict."""
    import numpy

    from voicepuppet import __version__, _core

    info = {"voicepuppet": __version__, "python": platform.python_version(),
            "numpy": numpy.__version__, "platform": platform.platform()}
    info.update({f"core_{k}": v for k, v in _core.build_info().items()})
    from threadpoolctl import threadpool_info

    blas = [lib for lib in threadpool_info() if lib.get("user_api") == "blas"]
    info["blas"] = ", ".join(f"{lib['internal_api']} {lib['version']}, {lib['num_threads']} "
                             f"thread{'s' if lib['num_threads'] != 1 else ''}"
                             for lib in blas) or "none found"
    return info


def _run(args) -> int:
    for key, value in collect().items():
        print(f"{key:>16}: {value}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="show versions, build type and compiler",
                       description="Show versions, build type, compiler and SIMD of the core.")
    p.set_defaults(func=_run)
