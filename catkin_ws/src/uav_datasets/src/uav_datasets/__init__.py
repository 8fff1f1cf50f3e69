"""The aerial data engine: labelled datasets rendered from the simulated world.

* ``uav_datasets.core``: pure configuration, viewpoint sampling, per-frame labelling from rendered
  instance ids and object geometry, COCO RLE, the text formats (COCO, YOLO, MOTChallenge, KITTI) and
  the dataset card's statistics.
* ``uav_datasets.shell``: rendering, workers, the output folder (resume, atomic writes), flights read
  from recorded runs, the contact sheet and the checks.
* ``uav_datasets.cli``: ``uav-dataset``.
"""
