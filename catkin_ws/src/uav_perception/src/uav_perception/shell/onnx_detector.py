"""An ONNX detector file, loaded and checked, run on images (onnxruntime, CPU).

:class:`OnnxDetector` opens a model of the format in :mod:`uav_perception.core.detection.learned`, checks its
declared inputs and outputs, runs it once on a blank image to check what it really returns, and then turns
images into ``RawDetection`` lists. A missing, unreadable or corrupt file, or one of another format, is a
:class:`~uav_perception.errors.ModelFileError` naming the file and what was expected.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uav_perception.core.detection.boxes import RawDetection
from uav_perception.core.detection.learned import (
    DecodeConfig,
    ModelSpec,
    TensorInfo,
    check_output,
    decode,
    letterbox,
    validate_io,
)
from uav_perception.errors import ModelFileError, ModelFormatError

__all__ = ["OnnxDetector", "model_class_names"]


def model_class_names(metadata: dict[str, str], path: str) -> list[str] | None:
    """The model's ``uav_classes`` metadata (a JSON list of class names), or ``None`` if it has none.

    Raises:
        ModelFormatError: the entry is not a JSON list of strings.
    """
    raw = metadata.get("uav_classes")
    if raw is None:
        return None
    try:
        names = json.loads(raw)
    except json.JSONDecodeError:
        names = None
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        msg = f"{path}: metadata uav_classes must be a JSON list of class names, got {raw!r}"
        raise ModelFormatError(msg)
    return names


@dataclass(frozen=True)
class _Loaded:
    spec: ModelSpec
    class_names: list[str] | None
    num_classes: int


class OnnxDetector:
    """One ONNX detector session (CPU, ``threads`` intra-op threads)."""

    def __init__(self, path: str | Path, *, threads: int = 1, cfg: DecodeConfig | None = None) -> None:
        """Load and check ``path``.

        Raises:
            ModelFileError: the file is missing, unreadable or not an ONNX model.
            ModelFormatError: its inputs or outputs are not the documented format.
        """
        import onnxruntime as ort  # noqa: PLC0415 (a heavy import; only a detector needs it)

        self.path = str(Path(path).expanduser())
        self.cfg = cfg or DecodeConfig()
        p = Path(self.path)
        if not p.is_file():
            msg = (
                f"{self.path}: no such model file; expected an ONNX detector "
                "(docs/detector.md; the shipped one is uav_perception/models/uav_detector.onnx)"
            )
            raise ModelFileError(msg)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(self.path, sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as err:  # onnxruntime raises its own Fail/InvalidGraph/... types
            msg = f"{self.path}: not a loadable ONNX model ({type(err).__name__}: {str(err).splitlines()[0][:200]})"
            raise ModelFileError(msg) from err
        inputs = [TensorInfo(i.name, tuple(i.shape), str(i.type)) for i in self.session.get_inputs()]
        outputs = [TensorInfo(o.name, tuple(o.shape), str(o.type)) for o in self.session.get_outputs()]
        spec = validate_io(self.path, inputs, outputs)
        names = model_class_names(dict(self.session.get_modelmeta().custom_metadata_map), self.path)
        h, w = spec.input_hw or (64, 64)
        blank, _ = letterbox(np.zeros((h, w, 3), dtype=np.uint8), spec.input_hw)
        try:
            out = self.session.run(None, {spec.input_name: blank})[0]
        except Exception as err:
            msg = f"{self.path}: the model fails on a blank {w}x{h} image ({type(err).__name__}: {str(err)[:200]})"
            raise ModelFormatError(msg) from err
        num = check_output(self.path, np.asarray(out), spec, None if names is None else len(names))
        self._loaded = _Loaded(spec, names, num)

    @property
    def spec(self) -> ModelSpec:
        return self._loaded.spec

    @property
    def class_names(self) -> list[str] | None:
        """Column ``k``'s class name from the model's metadata (``None``: column ``k`` is class id ``k``)."""
        return self._loaded.class_names

    @property
    def num_classes(self) -> int:
        return self._loaded.num_classes

    def detect(self, image_rgb: np.ndarray, class_ids: list[int]) -> tuple[list[RawDetection], Counter[str]]:
        """Detections in the image's pixels (``boxes.py`` convention) and the discards by reason.

        ``class_ids[k]``: the range's class id of the model's column ``k``.
        """
        tensor, lb = letterbox(image_rgb, self.spec.input_hw)
        out = np.asarray(self.session.run(None, {self.spec.input_name: tensor})[0])
        check_output(self.path, out, self.spec, self.num_classes)
        h, w = image_rgb.shape[:2]
        return decode(out, lb, width_px=w, height_px=h, class_ids=class_ids, cfg=self.cfg)
