"""The package's version, as installed (``0+unknown`` for a source tree never installed)."""

from __future__ import annotations


def package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("handeye-jax")
    except PackageNotFoundError:
        return "0+unknown"
