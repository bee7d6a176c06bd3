"""Package APIs whose names load on first use (PEP 562), so that importing a light module of a
package (geometry, say) does not import the heavy ones (Open3D, numba) beside it."""
from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_api(package: str, home: Mapping[str, str]
             ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package`` whose public names live in its
    submodules as ``home`` says ({name: submodule}); a name is imported when first asked for
    and then kept on the package."""
    def get_attribute(name: str) -> Any:
        try:
            module = home[name]
        except KeyError:
            raise AttributeError(f'module {package!r} has no attribute {name!r}') from None
        value = getattr(importlib.import_module(f'{package}.{module}'), name)
        setattr(sys.modules[package], name, value)
        return value

    def list_names() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(home))

    return get_attribute, list_names
