"""Names that become file or folder names (tips, objects, fingers), checked in one place.

A scene value or a command's argument that ends up in a path must not hold a separator or
``..`` (it could name a folder outside ``--out``), so such names are restricted to a safe
form: 1-32 letters, digits, ``_``, ``+`` or ``-``, starting with a letter or digit.
"""

from __future__ import annotations

import re

from ._spec import SceneError

SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_+-]{0,31}$")
"""The form of a name that becomes part of a file or folder name."""


def check_name(value: object, key: str) -> str:
    """``value`` if it can become part of a file or folder name.

    Raises
    ------
    SceneError
        (a ValueError) naming ``key`` and the allowed form.
    """
    if not isinstance(value, str) or not SAFE_NAME.match(value):
        raise SceneError(f"{key}={value!r} is not allowed: it names files or folders, so 1-32 "
                         "letters, digits, '_', '+' or '-', starting with a letter or digit")
    return value
