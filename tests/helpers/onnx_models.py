"""Hand-made ONNX detectors for tests (built with ``onnx.helper``; no training, no download).

:func:`constant_detector` returns the same candidates for every image, in the detector format
(``uav_perception.core.detection.learned``): ``[1, 4 + C, N]`` rows ``cx, cy, w, h, scores...``. The output
depends on the input (``+ 0 * mean(image)``), so the runtime cannot fold the graph away.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

__all__ = ["constant_detector"]


def constant_detector(
    path: Path,
    candidates: Sequence[Sequence[float]],
    *,
    input_shape: Sequence[int | str] = (1, 3, 480, 640),
    output_shape: Sequence[int | str] | None = None,
    class_names: Sequence[str] | None = ("person", "vehicle"),
    input_dtype: int = TensorProto.FLOAT,
) -> Path:
    """Write a model whose output is ``candidates`` (each ``[cx, cy, w, h, score_0, ...]``), transposed to
    ``[1, 4 + C, N]``. ``output_shape`` overrides the declared output shape (a wrong-shape model: the array it
    returns is reshaped to it)."""
    table = np.asarray(candidates, dtype=np.float32).reshape(len(candidates), -1).T[None]  # [1, 4 + C, N]
    declared = list(output_shape) if output_shape is not None else list(table.shape)
    value = table.reshape(list(declared)) if output_shape is not None else table
    const = numpy_helper.from_array(np.ascontiguousarray(value), name="table")
    zero = numpy_helper.from_array(np.zeros((), np.float32), name="zero")
    nodes = [
        helper.make_node("Cast", ["images"], ["images_f"], to=TensorProto.FLOAT),
        helper.make_node("ReduceMean", ["images_f"], ["m"], keepdims=0),
        helper.make_node("Mul", ["m", "zero"], ["m0"]),
        helper.make_node("Add", ["table", "m0"], ["output0"]),
    ]
    graph = helper.make_graph(
        nodes,
        "constant_detector",
        [helper.make_tensor_value_info("images", input_dtype, list(input_shape))],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, declared)],
        initializer=[const, zero],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    if class_names is not None:
        prop = model.metadata_props.add()
        prop.key, prop.value = "uav_classes", json.dumps(list(class_names))
    onnx.checker.check_model(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path
