"""``uav-train-detector``'s library: the data engine's COCO output read for training (``data``), the network and
its ONNX export (``model``, torch), the training loop (``train``, torch) and the held-out evaluation of an ONNX
model (``evaluate``, onnxruntime + pycocotools). torch is imported only by ``model`` and ``train``: it is an
opt-in dependency (requirements-train.txt, ``make train-detector``)."""
