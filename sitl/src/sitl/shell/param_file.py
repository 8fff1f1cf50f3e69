"""The persisted parameter file: values set over MAVLink survive a restart.

JSON, written atomically (temporary file + rename) after every accepted change;
only values that differ from the defaults are stored.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from sitl.errors import ParamFileError

__all__ = ["FORMAT", "ParamFile"]

FORMAT = "uav-sitl-params/1"


class ParamFile:
    def __init__(self, path: Path) -> None:
        self.path = path

    def load(self) -> dict[str, object]:
        """The stored values; an absent file means none.

        Raises:
            ParamFileError: the file exists but is not a parameter file.
        """
        if not self.path.exists():
            return {}
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            msg = f"{self.path}: cannot read parameter file ({err}); fix or delete it, or start with --reset-params"
            raise ParamFileError(msg) from err
        if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("params"), dict):
            msg = f"{self.path}: not a {FORMAT} parameter file; delete it or start with --reset-params"
            raise ParamFileError(msg)
        params: dict[str, object] = data["params"]
        return params

    def save(self, values: dict[str, float]) -> None:
        """Write ``values`` atomically.

        Raises:
            ParamFileError: the directory or file cannot be written.
        """
        payload = json.dumps({"format": FORMAT, "params": dict(sorted(values.items()))}, indent=1) + "\n"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".params-", dir=self.path.parent)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(payload)
            os.replace(tmp, self.path)
        except OSError as err:
            msg = f"{self.path}: cannot write parameter file: {err.strerror}"
            raise ParamFileError(msg) from err

    def reset(self) -> None:
        try:
            self.path.unlink(missing_ok=True)
        except OSError as err:
            msg = f"{self.path}: cannot delete parameter file: {err.strerror}"
            raise ParamFileError(msg) from err
